"""Closing the hand: which joint angles to close to, and how fast.

The hand model is public, so a policy may compute the grasp of the object it sees
(:func:`generators.grasp.grasp_angles`: each finger closes along its synergy until it
touches) for the category the task text names and the size it estimated. It closes
to the grasp of a slightly smaller object (:data:`GRIP_MARGIN`), a firm grip that
forgives an overestimated size. Without a known category it closes each finger to
the end of its synergy. The grasp, the fist and the hover height are the dataset's grasp
design's (:data:`generators.grasp.DEFAULT_DESIGN`), as the ground truth's.
"""

from __future__ import annotations

import numpy as np

from generators.grasp import DEFAULT_DESIGN, grasp_angles, grasp_hover
from generators.hand import JOINT_LOWER, JOINT_UPPER, REST_JOINTS
from generators.interception import minimum_jerk
from schemas.scene import GRASP_FRAMES, PALM_HOVER

#: Close to the grasp of an object this much smaller than the estimate.
GRIP_MARGIN = 0.85
#: The hand fully closed: every finger at the end of the design's synergy.
FIST = np.clip(np.asarray(DEFAULT_DESIGN.synergy_end), JOINT_LOWER, JOINT_UPPER)


def grip_angles(category: str | None, size: float | None, hand: str) -> np.ndarray:
    """(15,) joint angles to close to."""
    if category is None or size is None:
        return FIST.copy()
    return grasp_angles(category, round(float(size) * GRIP_MARGIN, 6), hand, DEFAULT_DESIGN)


def hover_over_top(category: str | None, size: float | None, hand: str) -> float:
    """The palm centre's height over the object's top the ground truth grasps ``category``
    of ``size`` from (the design's; a lying cylinder's with the palm across its axis, as
    the wrist reflex turns it); :data:`~schemas.scene.PALM_HOVER` when either is unknown."""
    if category is None or size is None:
        return PALM_HOVER
    return grasp_hover(category, round(float(size), 6), hand, DEFAULT_DESIGN)


def closing_joints(grip: np.ndarray, frames_since_start: int) -> np.ndarray:
    """(15,) joint angles ``frames_since_start`` frames after closing began (0 = still
    open): minimum jerk from rest to ``grip`` over ``GRASP_FRAMES`` frames, as the
    ground truth closes."""
    fraction = float(minimum_jerk(np.array(frames_since_start / (GRASP_FRAMES - 1))))
    return REST_JOINTS + fraction * (np.asarray(grip) - REST_JOINTS)
