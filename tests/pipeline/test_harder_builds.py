"""Each harder setting of paper A.11 builds byte-identically in this process and on two
Dask workers (the reference in this process: a one-worker cluster cost a cluster's start
and checked the same thing, Dask against Dask)."""

from __future__ import annotations

import pytest

from pipeline.jobs.build import build

#: The default run keeps obstacle-medium; the other two repeat its check on their settings.
SLOW = pytest.mark.slow(
    cover="tests/pipeline/test_harder_builds.py::test_a_harder_slice_builds_byte_identically_in_process_and_with_two_workers")


@pytest.mark.parametrize(
    "slice_name",
    [pytest.param("projectile-medium", marks=SLOW), "obstacle-medium", pytest.param("irregular-slow", marks=SLOW)],
)
def test_a_harder_slice_builds_byte_identically_in_process_and_with_two_workers(tmp_path, slice_name):
    hashes = []
    for workers in (0, 2):
        manifest = build(slice_name, tmp_path / str(workers), episodes=4, shard_size=2, resolution=32,
                         workers=workers, progress=False)
        hashes.append(manifest.hash)
    assert hashes[0] == hashes[1]
