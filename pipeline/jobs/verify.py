"""`catalog verify`: every listed file intact, and sampled shards rebuilt byte for byte.

Integrity (sha256, sizes, readable Parquet/MCAP, no stray temps) comes from
``catalog.tables.integrity``. Rebuilding re-executes each sampled shard through
:func:`pipeline.jobs.replay.replay_shard` (the one re-execution of a recording): the
episode stage, the renderer and the writers run again on the specs stored in the shard's
episodes table (so slices built from a user's ``--specs`` file verify too), and every
column and file's bytes are compared. Rollout sets are re-executed through
:func:`pipeline.jobs.replay.replay` (with their environment) instead.

Progress (with ``on_shard``, or ``progress=True``): a line per rebuilt episode on stderr,
at most one per 2 s plus the last (:class:`schemas.cli.ProgressMeter`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from catalog.store.manifest import Manifest, load_manifest
from catalog.store.records import ShardRecord
from catalog.store.storage import as_location
from catalog.store.versions import mismatch_note
from catalog.tables.integrity import verify_files
from catalog.tables.reader import open_folder
from pipeline.jobs.replay import check_rebuildable, private_seed, recorded_settings, replay, replay_shard
from schemas.cli import ProgressMeter
from schemas.errors import ReplayMismatch, ShardError, SpecError
from schemas.names import shorten
from schemas.runs import is_run


@dataclass(frozen=True)
class VerifyReport:
    slice: str
    shards_checked: int
    shards_rebuilt: int
    files_compared: int


def _sample_shards(manifest: Manifest, sample: int | None, rng: np.random.Generator) -> list[ShardRecord]:
    shards = list(manifest.shards)
    if sample is None or sample >= len(shards):
        return shards
    picks = rng.choice(len(shards), size=sample, replace=False)
    return [shards[i] for i in sorted(picks)]


def check_build_settings(directory: Path, manifest: Manifest) -> None:
    """ShardError unless this code can rebuild ``manifest``'s ground truth: its dataset
    version, and settings that are all :class:`BuildSettings`' (and valid)."""
    check_rebuildable(directory, manifest)
    recorded_settings(directory, manifest.settings)


def verify(
    directory: str | Path,
    sample: int | None = None,
    rng: np.random.Generator | None = None,
    on_shard: Callable[[ShardRecord], None] | None = None,
    progress: bool | None = None,
    test_seed: str | None = None,
) -> VerifyReport:
    """Check every file, then rebuild ``sample`` shards (all by default) and compare bytes.

    ``progress`` (default: whether ``on_shard`` is given) prints episode progress lines of
    the rebuild on stderr. A run drawn from a private seed needs it (``test_seed``)."""
    # the arguments before any file is read (the sha256 pass below reads the whole folder)
    if sample is not None and (isinstance(sample, bool) or not isinstance(sample, int) or sample < 1):
        raise SpecError(f"--sample must be an integer >= 1, got {shorten(repr(sample))}")
    rng = np.random.default_rng(0) if rng is None else rng
    if not isinstance(rng, np.random.Generator):
        raise SpecError(f"rng must be a numpy.random.Generator, got {shorten(repr(rng))}")
    directory = as_location(directory, "directory")
    private_seed(directory, load_manifest(directory), test_seed)  # a missing or wrong seed: one line, before the work
    manifest = verify_files(directory)
    shards = _sample_shards(manifest, sample, rng)
    if is_run(manifest.extra):
        replay(directory, shards=[s.first for s in shards], test_seed=test_seed)
        return VerifyReport(manifest.slice, len(manifest.shards), len(shards), 0)
    check_build_settings(directory, manifest)
    readers = {reader.record.first: reader for reader in open_folder(directory).shards}  # hashes checked above
    show = on_shard is not None if progress is None else progress
    meter = ProgressMeter(sum(s.end - s.first for s in shards)) if show else None
    finished = [0, 0]  # episodes, frames of the shards rebuilt

    def report(first: int, end: int, done: int, frames: int) -> None:
        if meter is not None and done < end - first:  # a shard's last episode is counted when it is compared
            meter.update(finished[0] + done, finished[1] + frames, prefix=f"[rebuilding {first}-{end - 1}]")

    compared = 0
    for number, shard in enumerate(shards, 1):
        try:
            replay_shard(readers[shard.first], manifest.settings, None, report=report)
        except ReplayMismatch as exc:
            raise ShardError(f"{directory / str(getattr(exc, 'file', ''))}: rebuilding gives different bytes ({exc})"
                             f"{mismatch_note(manifest.versions)}") from None
        compared += len(shard.files)
        finished[0] += shard.end - shard.first
        finished[1] += shard.frames
        if meter is not None:
            meter.update(finished[0], finished[1], prefix=f"[{number}/{len(shards)} shards rebuilt]")
        if on_shard is not None:
            on_shard(shard)
    return VerifyReport(manifest.slice, len(manifest.shards), len(shards), compared)
