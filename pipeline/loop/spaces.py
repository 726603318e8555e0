"""The closed loop's observation and action: their typed shapes and Gymnasium spaces.

Every observation lies in :func:`observation_space` exactly, dtypes and shapes included,
so Gymnasium's passive checker runs under ``gymnasium.make`` and stays silent; the
bounds are what the environment itself enforces (docs/guides/your-policy.md, "The environment in detail").
:class:`Observation` and :class:`StepInfo` are the same contract for the type checker.
"""

from __future__ import annotations

import math
import string
from typing import TypedDict

import numpy as np
from gymnasium import spaces
from gymnasium.spaces import utils as space_utils

from generators.hand import (
    JOINT_LOWER,
    JOINT_UPPER,
    REST_JOINTS,
    REST_PALM,
    SEGMENT_LENGTHS,
    WRIST_OFFSET,
    root_positions,
)
from pipeline.policies.base import Observation
from schemas import scene
from schemas.scene import PALM_BOX
from schemas.spec import MAX_TEXT
from schemas.versions import FPS

__all__ = [
    "ACTION_WIDTH", "HAND_REACH", "INFO_KEYS", "MAX_FRAMES", "OBSERVATION_KEYS", "PALM_BOX", "PALM_HIGH", "PALM_LOW",
    "REST_STATE", "FrameIndex", "Instruction", "Observation", "ObserveWindow", "StepInfo", "action_space", "empty_window",
    "observation_space",
]

PALM_LOW = np.array(scene.PALM_LOW)
PALM_HIGH = np.array(scene.PALM_HIGH)
ACTION_WIDTH = 18
#: The hand's rest state as an action (palm xyz + 15 joints, float32).
REST_STATE = np.concatenate([REST_PALM[:3], REST_JOINTS]).astype(np.float32)
OBSERVATION_KEYS = tuple(Observation.__annotations__)
#: Frame indices the observation space allows (``frame_index`` < MAX_FRAMES).
MAX_FRAMES = 100_000
#: How far any joint or keypoint lies from the palm centre, at most (the longest chain,
#: finger root plus its three segments, rounded up to 0.1 unit; the wrist is 0.5 away).
HAND_REACH = math.ceil(10 * max(
    float(np.max(np.linalg.norm(root_positions("right"), axis=1) + SEGMENT_LENGTHS.sum(axis=1))),
    float(np.linalg.norm(WRIST_OFFSET)),
)) / 10
#: Euler angle ranges (roll, pitch, yaw) of ``schemas.rotations.matrix_to_euler``.
EULER_LOW = np.array([-np.pi, -np.pi / 2, -np.pi])
EULER_HIGH = np.array([np.pi, np.pi / 2, np.pi])


class StepInfo(TypedDict):
    """``info`` of ``reset`` and ``step``: the events so far and this frame's distances."""

    localized: bool
    grasped: bool
    #: Acting frames from the first acting frame to the event, -1 before it.
    t_loc: int
    t_gra: int
    palm_distance: float
    fingertip_distance: float


INFO_KEYS = tuple(StepInfo.__annotations__)


def empty_window(resolution: int) -> np.ndarray:
    """The (0, H, W, 3) uint8 ``observe_images`` of every observation after the first."""
    return np.zeros((0, resolution, resolution, 3), dtype=np.uint8)


def pose_bounds(count: int, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """float32 (low, high) of ``count`` poses (x, y, z, roll, pitch, yaw): positions in
    the palm box grown by ``reach``, angles in the Euler ranges."""
    low = np.tile(np.concatenate([PALM_LOW - reach, EULER_LOW]), count)
    high = np.tile(np.concatenate([PALM_HIGH + reach, EULER_HIGH]), count)
    return low.astype(np.float32), high.astype(np.float32)


class ObserveWindow(spaces.Sequence):
    """The observe window: a stacked sequence of (H, W, 3) uint8 images, (K, H, W, 3)
    with K = ``observe_frames`` in the first observation, (0, H, W, 3) afterwards.

    Unlike a plain ``Sequence`` it is flattenable, to zero entries (:mod:`pipeline.loop.env`,
    "Spaces"): ``flatten`` drops the window, ``unflatten`` gives an empty one, so a
    flattened observation is the current frame's state. Sampling, ``contains`` and
    batching are ``Sequence``'s."""

    def __init__(self, image: spaces.Box, seed: int | np.random.Generator | None = None):
        super().__init__(image, stack=True, seed=seed)
        self.dtype = np.dtype(np.uint8)  # what it flattens to (an empty uint8 Box)

    @property
    def is_np_flattenable(self) -> bool:  # type: ignore[override]  # Sequence says Literal[False]
        return True

    def __repr__(self) -> str:
        return f"ObserveWindow({self.feature_space})"


# Gymnasium's flattening functions dispatch on the space's type; these apply to
# ObserveWindow only (a plain Sequence stays unflattenable)
@space_utils.flatdim.register(ObserveWindow)
def flatdim_window(space: ObserveWindow) -> int:
    return 0


@space_utils.flatten_space.register(ObserveWindow)
def flatten_space_window(space: ObserveWindow) -> spaces.Box:
    return spaces.Box(0, 255, (0,), np.uint8)


@space_utils.flatten.register(ObserveWindow)
def flatten_window(space: ObserveWindow, x: object) -> np.ndarray:  # type: ignore[misc]  # mypy cannot match a generic Space[T] fallback
    return np.zeros(0, dtype=np.uint8)


@space_utils.unflatten.register(ObserveWindow)
def unflatten_window(space: ObserveWindow, x: object) -> np.ndarray:  # type: ignore[misc]  # mypy cannot match a generic Space[T] fallback
    return np.zeros((0, *(space.feature_space.shape or ())), dtype=np.uint8)


class FrameIndex(spaces.Discrete):
    """``frame_index``: a ``Discrete(MAX_FRAMES)`` that flattens to one entry, the index
    itself (a plain ``Discrete`` flattens to a one-hot vector of MAX_FRAMES entries)."""

    def __repr__(self) -> str:
        return f"FrameIndex({self.n})"


@space_utils.flatdim.register(FrameIndex)
def flatdim_frame(space: FrameIndex) -> int:
    return 1


@space_utils.flatten_space.register(FrameIndex)
def flatten_space_frame(space: FrameIndex) -> spaces.Box:
    return spaces.Box(int(space.start), int(space.start + space.n - 1), (1,), np.int64)


@space_utils.flatten.register(FrameIndex)
def flatten_frame(space: FrameIndex, x: object) -> np.ndarray:  # type: ignore[misc]  # mypy cannot match a generic Space[T] fallback
    return np.array([x], dtype=np.int64)


@space_utils.unflatten.register(FrameIndex)
def unflatten_frame(space: FrameIndex, x: np.ndarray) -> np.int64:  # type: ignore[misc]  # mypy cannot match a generic Space[T] fallback
    return np.int64(x[0])


class Instruction(spaces.Text):
    """``text``: a ``Text`` space that flattens to zero entries, like the observe window
    (a plain ``Text`` flattens to MAX_TEXT character indices); ``unflatten`` gives ""."""

    def __repr__(self) -> str:
        return f"Instruction({self.min_length}, {self.max_length})"


@space_utils.flatdim.register(Instruction)
def flatdim_text(space: Instruction) -> int:
    return 0


@space_utils.flatten_space.register(Instruction)
def flatten_space_text(space: Instruction) -> spaces.Box:
    return spaces.Box(0, 0, (0,), np.int32)


@space_utils.flatten.register(Instruction)
def flatten_text(space: Instruction, x: object) -> np.ndarray:  # type: ignore[misc]  # mypy cannot match a generic Space[T] fallback
    return np.zeros(0, dtype=np.int32)


@space_utils.unflatten.register(Instruction)
def unflatten_text(space: Instruction, x: object) -> str:  # type: ignore[misc]  # mypy cannot match a generic Space[T] fallback
    return ""


def box(low: np.ndarray, high: np.ndarray) -> spaces.Box:
    """A float32 Box between two arrays of the same shape."""
    return spaces.Box(low.astype(np.float32), high.astype(np.float32), low.shape, np.float32)


def observation_space(resolution: int) -> spaces.Dict:
    """The space of every observation at ``resolution`` (module docstring)."""
    image = spaces.Box(0, 255, (resolution, resolution, 3), np.uint8)
    palm_low, palm_high = pose_bounds(1, 0.0)
    joint_poses_low, joint_poses_high = pose_bounds(15, HAND_REACH)
    keypoints_low, keypoints_high = pose_bounds(6, HAND_REACH)
    return spaces.Dict(
        {
            "image": image,
            "palm_pose": box(palm_low, palm_high),
            "joint_angles": box(JOINT_LOWER, JOINT_UPPER),
            "joint_poses": box(joint_poses_low, joint_poses_high),
            "keypoints": box(keypoints_low, keypoints_high),
            "text": Instruction(max_length=MAX_TEXT, min_length=0, charset=string.printable),
            "frame_index": FrameIndex(MAX_FRAMES),
            "timestamp": spaces.Box(0.0, (MAX_FRAMES - 1) / FPS, (), np.float64),
            "observe_images": ObserveWindow(image),
        }
    )


def action_space() -> spaces.Box:
    """The action Box [palm box, joint limits] (absolute targets, not normalised)."""
    return box(np.concatenate([PALM_LOW, JOINT_LOWER]), np.concatenate([PALM_HIGH, JOINT_UPPER]))
