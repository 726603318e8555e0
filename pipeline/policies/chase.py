"""``chase``: moves toward where it sees the object now, from pixels only.

Each step it localises the object in the current frame (:mod:`.perception`) and
moves the palm toward the hover point over it (the object's estimated top plus the
grasp design's hover, :func:`~pipeline.policies.grip.hover_over_top`) by a fixed fraction :data:`GAIN` of the remaining
distance, at most :data:`MAX_STEP` per frame: a proportional visual servo. When the
hand hides the object the last sighting stays the target. Once the palm is within
:data:`CLOSE_DISTANCE` of the target in the XZ plane it closes the hand (minimum
jerk over ``GRASP_FRAMES`` frames) while it keeps following.

It has no model of the motion, so it trails a moving target by about
``speed / (GAIN x FPS)``: it catches slow objects and the turning points of
oscillations, and falls behind fast ones. Deterministic; numpy only.
"""

from __future__ import annotations

import numpy as np

from generators.hand import REST_JOINTS
from pipeline.policies.base import Observation, Task
from pipeline.policies.grip import closing_joints, grip_angles, hover_over_top
from pipeline.policies.perception import ObjectLocator
from schemas.errors import PolicyError

#: Fraction of the remaining distance covered per frame.
GAIN = 0.3
#: Longest palm step per frame (units; 0.4 per frame = 8 units/s).
MAX_STEP = 0.4
#: Start closing when the palm is this close (XZ) to the target.
CLOSE_DISTANCE = 0.2
#: Sightings showing less of the object than this are ignored.
MIN_COVERAGE = 0.1


class ChasePolicy:
    """Proportional visual servo toward the latest sighting (module docstring)."""

    name = "chase"
    action_horizon = 1
    privileged = False

    def __init__(self) -> None:
        self._locator: ObjectLocator | None = None

    def reset(self, task: Task) -> None:
        self._locator = ObjectLocator(str(task["text"]), int(task["resolution"]))
        self._hand = str(task["hand"])
        self._target: np.ndarray | None = None
        self._close_start: int | None = None
        self._grip: np.ndarray | None = None

    def act(self, obs: Observation) -> np.ndarray:
        if self._locator is None:
            raise PolicyError("act() before reset()")
        k = int(obs["frame_index"])
        palm = np.asarray(obs["palm_pose"], dtype=np.float64)[:3]
        seen = self._locator.locate(obs["image"], obs["palm_pose"], obs["joint_poses"], obs["keypoints"])
        if seen is not None and seen.coverage >= MIN_COVERAGE:
            self._target = seen.position[[0, 2]]
        if self._target is None:
            goal = palm
        else:
            category = self._locator.category.name if self._locator.category else None
            hover = hover_over_top(category, self._locator.size, self._hand)
            goal = np.array([self._target[0], self._locator.top_height + hover, self._target[1]])
        step = GAIN * (goal - palm)
        length = float(np.linalg.norm(step))
        if length > MAX_STEP:
            step *= MAX_STEP / length
        if (
            self._close_start is None
            and self._target is not None
            and np.hypot(*(palm[[0, 2]] - self._target)) <= CLOSE_DISTANCE
        ):
            self._close_start = k
            category = self._locator.category.name if self._locator.category else None
            self._grip = grip_angles(category, self._locator.size, self._hand)
        if self._close_start is None or self._grip is None:
            joints = REST_JOINTS
        else:
            joints = closing_joints(self._grip, k + 1 - self._close_start)
        return np.concatenate([palm + step, joints]).astype(np.float32)
