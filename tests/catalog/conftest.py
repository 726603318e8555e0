"""Synthetic episodes for the store's tests, reusable by the dataloader's tests.

Plain builder functions (``make_spec``, ``make_frames``, ``make_images``,
``make_episode``, ``write_slice``) plus fixtures around them. Every builder takes an
explicit ``numpy.random.Generator`` or seed; nothing touches global RNGs.
"""

from __future__ import annotations

import collections
from pathlib import Path

import cv2
import numpy as np
import pytest

from catalog.store.manifest import CodeInfo, Manifest, write_manifest
from catalog.tables.shard import ShardWriter
from schemas.frames import EpisodeFrames
from schemas.motion import ArcToken, LineToken, Motion
from schemas.scene import GRASP_FRAMES
from schemas.spec import EpisodeSpec
from schemas.tables import ARRAY_WIDTHS
from schemas.versions import DATASET_VERSION

RESOLUTION = 32
SETTINGS = {"fps": 20, "resolution": RESOLUTION, "image_format": "jpeg", "jpeg_quality": 90, "dataset_version": DATASET_VERSION}
CODE = CodeInfo("0.1.0", "0123456789abcdef0123456789abcdef01234567")


def make_spec(index: int, slice_name: str = "linear-fast", num_frames: int | None = None) -> EpisodeSpec:
    """A valid observe-before-act spec; odd indices use a line then an arc, on a rolling can."""
    if index % 2 == 0:
        motion = Motion.of(LineToken(start=(-1.0, 4.0), direction=0.3, speed=0.5, acceleration=0.0, duration=4.0))
        obj, hand = "tennis_ball", "right"
    else:
        motion = Motion.of(
            LineToken(start=(1.0, 3.0), direction=1.2, speed=0.4, acceleration=0.1, duration=2.0),
            ArcToken(centre=(0.0, 5.0), radius=1.0, angular_velocity=0.8, start_angle=0.0, turn=-1, duration=2.0),
        )
        obj, hand = "soda_can", "left"
    observe = 3 + index % 3
    minimum = observe + 10 + GRASP_FRAMES + 1
    return EpisodeSpec(
        slice=slice_name,
        episode_index=index,
        seed=7,
        motion_type="linear",
        motion=motion,
        object=obj,
        object_size=1.0 + 0.1 * (index % 4),
        hand=hand,
        rollout_format="observe-before-act",
        intercept_setting="fast",
        observe_frames=observe,
        num_frames=minimum + index % 5 if num_frames is None else num_frames,
        text=f"grasp the moving {obj} (episode {index})",
    )


def make_frames(spec: EpisodeSpec, rng: np.random.Generator, num_frames: int | None = None) -> EpisodeFrames:
    """Random float32 states of the right shapes, phases following the spec's timeline."""
    n = spec.num_frames if num_frames is None else num_frames
    phase = np.full(n, 3, dtype=np.int8)
    phase[: min(n, spec.intercept_frame + GRASP_FRAMES)] = 2
    phase[: min(n, spec.intercept_frame)] = 1
    phase[: min(n, spec.observe_frames)] = 0

    def f32(*shape: int) -> np.ndarray:
        return rng.standard_normal(shape).astype(np.float32)

    object_pose = f32(n, 7)
    quats = f32(n, 4)
    object_pose[:, 3:] = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    return EpisodeFrames(
        phase=phase,
        object_pose=object_pose,
        object_velocity=f32(n, ARRAY_WIDTHS["object_velocity"]),
        palm_pose=f32(n, 6),
        joint_angles=f32(n, 15),
        joint_poses=f32(n, 90),
        keypoints=f32(n, 36),
        action=f32(n, 18),
        fingertip_distance=np.abs(f32(n)),
        palm_distance=np.abs(f32(n)),
        grasp_angles=f32(15),
    )


def make_images(n: int, rng: np.random.Generator, size: int = RESOLUTION) -> list[bytes]:
    """``n`` tiny random JPEGs (RGB ``size`` x ``size``)."""
    images = []
    for _ in range(n):
        pixels = rng.integers(0, 256, size=(size, size, 3), dtype=np.uint8)
        ok, encoded = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        images.append(encoded.tobytes())
    return images


def make_episode(index: int, seed: int = 0, **spec_kwargs) -> tuple[EpisodeSpec, EpisodeFrames, list[bytes]]:
    """Spec, frames and images of one episode; the content depends only on (index, seed)."""
    rng = np.random.default_rng([seed, index])
    spec = make_spec(index, **spec_kwargs)
    frames = make_frames(spec, rng)
    return spec, frames, make_images(frames.num_frames, rng)


def write_slice(
    root: Path, episodes: int = 5, shard_size: int = 2, seed: int = 0, settings: dict | None = None
) -> Manifest:
    """A complete folder: shards of synthetic episodes plus its catalog.json."""
    settings = dict(SETTINGS if settings is None else settings)
    records = []
    for first in range(0, episodes, shard_size):
        end = min(first + shard_size, episodes)
        with ShardWriter(root, first, end, settings) as writer:
            for i in range(first, end):
                writer.add_episode(*make_episode(i, seed))
        records.append(writer.record)
    manifest = Manifest.create("linear-fast", 7, settings, records, code=CODE)
    write_manifest(root, manifest)
    return manifest


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture
def slice_dir(tmp_path: Path) -> Path:
    """A built synthetic slice of 5 episodes in 3 shards."""
    root = tmp_path / "linear-fast"
    write_slice(root)
    return root


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """A written slice of 6 episodes in shards of 2 (a module may define its own ``built``)."""
    root = tmp_path_factory.mktemp("built6") / "linear-fast"
    write_slice(root, episodes=6, shard_size=2)
    return root


def frame_keys(batches) -> collections.Counter:
    """How often each (episode_index, frame_index) occurs in torch ``batches``."""
    seen: collections.Counter = collections.Counter()
    for batch in batches:
        for e, f in zip(batch["episode_index"].tolist(), batch["frame_index"].tolist()):
            seen[(e, f)] += 1
    return seen
