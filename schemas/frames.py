"""Per-frame states of one episode as numpy arrays: what the episode stage and the
closed loop produce, and what the renderer and the shard writers consume."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from schemas.errors import SpecError
from schemas.scene import PHASES
from schemas.tables import ARRAY_WIDTHS

FRAME_ARRAYS = ("object_pose", "object_velocity", "palm_pose", "joint_angles", "joint_poses", "keypoints", "action")


@dataclass(frozen=True)
class EpisodeFrames:
    """States and actions of ``n`` frames (float32 arrays of the contract's widths).

    ``phase`` holds indices into :data:`schemas.scene.PHASES`. ``palm_distance`` is the
    palm centre's XZ distance to the object's centre (the localization event);
    ``fingertip_distance`` the minimum fingertip distance to the object's surface.
    """

    phase: np.ndarray  # (n,) int8
    object_pose: np.ndarray  # (n, 7) x y z qx qy qz qw
    object_velocity: np.ndarray  # (n, 3)
    palm_pose: np.ndarray  # (n, 6) x y z roll pitch yaw
    joint_angles: np.ndarray  # (n, 15)
    joint_poses: np.ndarray  # (n, 90)
    keypoints: np.ndarray  # (n, 36)
    action: np.ndarray  # (n, 18)
    fingertip_distance: np.ndarray  # (n,)
    palm_distance: np.ndarray  # (n,)
    grasp_angles: np.ndarray  # (15,)
    #: (n,) the hand's clearance from the scene's obstacles (generators.clearance), None
    #: for a scene without obstacles.
    obstacle_clearance: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("phase", *FRAME_ARRAYS, "fingertip_distance", "palm_distance", "grasp_angles"):
            value = getattr(self, name)
            if not isinstance(value, np.ndarray):
                raise SpecError(f"{name} must be a numpy array, got {type(value).__name__}")
        if self.phase.ndim != 1 or not np.issubdtype(self.phase.dtype, np.integer):
            raise SpecError(f"phase must be a 1-D integer array, got {self.phase.dtype} {self.phase.shape}")
        n = len(self.phase)
        if n == 0:
            raise SpecError("an episode needs at least one frame")
        for name in FRAME_ARRAYS:
            value = getattr(self, name)
            if value.shape != (n, ARRAY_WIDTHS[name]):
                raise SpecError(f"{name} must have shape {(n, ARRAY_WIDTHS[name])}, got {value.shape}")
        for name in ("fingertip_distance", "palm_distance"):
            if getattr(self, name).shape != (n,):
                raise SpecError(f"{name} must have shape {(n,)}, got {getattr(self, name).shape}")
        clearance = self.obstacle_clearance
        if clearance is not None and (not isinstance(clearance, np.ndarray) or clearance.shape != (n,)):
            raise SpecError(f"obstacle_clearance must be None or an array of shape {(n,)}, got {clearance!r:.80}")
        if self.grasp_angles.shape != (15,):
            raise SpecError(f"grasp_angles must have shape (15,), got {self.grasp_angles.shape}")
        if self.phase.min() < 0 or self.phase.max() >= len(PHASES):
            raise SpecError(f"phase indices must lie in [0, {len(PHASES)}), got {np.unique(self.phase)}")

    @property
    def num_frames(self) -> int:
        return len(self.phase)

    @property
    def phase_names(self) -> list[str]:
        return [PHASES[i] for i in self.phase]
