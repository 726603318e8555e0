"""One determinism test over the whole slice registry (dm_control style): for every
slice, an episode's spec, ground-truth arrays and rendered JPEG bytes are the same
generated alone, among others, twice, and in a fresh interpreter. (Shard files are
compared byte for byte across worker counts and schedulers in test_build.py.)"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from generators.encode import encode_jpeg
from generators.recipe import slice_specs, spec_for
from generators.render import Renderer
from pipeline.stages.episode import episode
from schemas.frames import FRAME_ARRAYS
from schemas.slices import SLICES
from tests.pipeline.in_thread import fresh_json

RESOLUTION = 32
#: Episode indices whose specs are checked in every slice: the first, and one past the first batch.
INDICES = (0, 5)
#: The episode of every slice whose arrays and frames are fingerprinted (one past the first
#: batch: its spec is drawn after others; a second one exercised the same code at twice the cost).
FINGERPRINTED = (5,)


def fingerprint(slice_name: str, index: int, renderer: Renderer) -> str:
    """sha256 over the spec, every state array and the JPEG bytes of the episode."""
    spec = spec_for(slice_name, index)
    frames = episode(spec)
    digest = hashlib.sha256(spec.to_json().encode())
    for name in FRAME_ARRAYS + ("fingertip_distance", "palm_distance", "grasp_angles", "phase"):
        digest.update(np.ascontiguousarray(getattr(frames, name)).tobytes())
    for image in renderer.render_episode(frames, spec.object, spec.object_size, spec.hand, obstacles=spec.obstacles):
        digest.update(encode_jpeg(image))
    return digest.hexdigest()


def fingerprints() -> dict[str, str]:
    with Renderer(RESOLUTION) as renderer:
        return {f"{name}:{i}": fingerprint(name, i, renderer) for name in SLICES for i in FINGERPRINTED}


@pytest.fixture(scope="module")
def reference() -> dict[str, str]:
    return fingerprints()


@pytest.mark.parametrize("slice_name", sorted(SLICES))
def test_episode_alone_equals_episode_among_many(slice_name):
    batch = list(slice_specs(slice_name, max(INDICES) + 1))
    for i in INDICES:
        alone = spec_for(slice_name, i)  # drawn once: a second draw cost as much and compared the same
        assert batch[i] == alone
        assert batch[i].to_json() == alone.to_json()


@pytest.mark.slow(cover="tests/pipeline/test_determinism.py::test_every_slice_is_the_same_in_a_fresh_interpreter")
def test_every_slice_is_the_same_twice_and_in_another_renderer(reference):
    """A second pass in this process (4 CPU s). The default run compares this process's pass
    with a fresh interpreter's (another renderer, another process, after whatever this one
    ran before), and re-executes folders in the process that built them (test_replay.py,
    test_renderer_choice.py's replay)."""
    assert fingerprints() == reference


def test_every_slice_is_the_same_in_a_fresh_interpreter(reference):
    assert fresh_json("tests.pipeline.test_determinism", "fingerprints", "12345") == reference
