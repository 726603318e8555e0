"""Grasps at other palm placements, for the hold test's investigation (:mod:`generators.hold`).

:func:`generators.grasp.grasp_angles` closes each finger along its synergy until it
touches the object with the palm :data:`schemas.scene.PALM_HOVER` over the object's top,
centred. :func:`closing_angles` does the same with the palm anywhere (an offset from
that placement), so that ``benchmarks/hold.py`` can ask which placements of this hand
hold which objects. "This hand" is the splayed thumb of datasets up to 4.x
(:data:`generators.hand.SPLAYED_THUMB`, :data:`generators.grasp.SYNERGY_END`): pass
``geometry=SPLAYED_THUMB`` to :func:`generators.hold.hold_test` with these grasps.
"""

from __future__ import annotations

import numpy as np

from generators.contact import signed_distance_local
from generators.grasp import SYNERGY_END
from generators.hand import FINGER_RADII, JOINT_LOWER, JOINT_UPPER, REST_JOINTS, SPLAYED_THUMB, chain_frames
from schemas.objects import object_category
from schemas.scene import PALM_HOVER

#: Closure fractions tried, and points sampled per finger segment (as generators.grasp).
GRID = 97
SAMPLES_PER_SEGMENT = 4


def hover_palm(category: str, size: float, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(6,) the palm pose over the object resting at the origin (its centre at its half
    height), palm down, moved by ``offset`` from the ground truth's hover point."""
    cat = object_category(category)
    top = 2.0 * cat.half_height(size)
    return np.array([offset[0], top + PALM_HOVER + offset[1], offset[2], 0.0, 0.0, 0.0])


def closing_angles(category: str, size: float, side: str, palm_pose: np.ndarray) -> np.ndarray:
    """(15,) each finger of the splayed hand closed along its synergy to the last sampled
    fraction before it touches the object (resting at the origin, canonical placement), or fully."""
    cat = object_category(category)
    grid = np.linspace(0.0, 1.0, GRID)
    q = REST_JOINTS + grid[:, None] * (SYNERGY_END.reshape(15) - REST_JOINTS)
    pos, _ = chain_frames(np.repeat(np.asarray(palm_pose, dtype=np.float64)[None], GRID, axis=0), q, side, SPLAYED_THUMB)
    w = np.linspace(0.0, 1.0, SAMPLES_PER_SEGMENT, endpoint=False)
    starts, ends = pos[:, :, :3], pos[:, :, 1:]
    points = starts[:, :, :, None] + w[:, None] * (ends - starts)[:, :, :, None]
    points = np.concatenate([points.reshape(GRID, 5, -1, 3), pos[:, :, 3:]], axis=2)
    centre = np.array([0.0, cat.half_height(size), 0.0])
    clearance = signed_distance_local(points - centre, cat.shape, cat.scaled_dims(size), cat.geometry.axis(cat.lying))
    clearance = clearance.min(axis=-1) - FINGER_RADII
    closure = np.ones(5)
    for f in range(5):
        hit = np.flatnonzero(clearance[:, f] <= 0.0)
        if len(hit):
            closure[f] = grid[max(int(hit[0]) - 1, 0)]
    angles = (closure[:, None] * SYNERGY_END).reshape(15)
    return np.clip(angles, JOINT_LOWER, JOINT_UPPER)


def resting_pose(category: str, size: float) -> np.ndarray:
    """(7,) the object at rest at the origin in its canonical placement."""
    return np.array([0.0, object_category(category).half_height(size), 0.0, 0.0, 0.0, 0.0, 1.0])
