"""The ground-truth grasp configuration, sized to the object.

The hand hovers with its palm centre :data:`schemas.scene.PALM_HOVER` above the
object's top, right above its centre, palm down. Each finger then closes along a
fixed synergy (its three joints in a fixed ratio) until its capsule first touches the
object, or to the synergy's end if it never does. So larger objects get less flexion.
The object sits in a canonical placement: a lying cylinder's axis across the palm
(along world X, as when it rolls toward or away from the camera), an upright one's
vertical, a box aligned with the world axes.
"""

from __future__ import annotations

import functools
import math
import numbers

import numpy as np

from generators.contact import signed_distance_local
from generators.hand import (
    FINGER_RADII,
    JOINT_LOWER,
    JOINT_UPPER,
    REST_JOINTS,
    SIDES,
    chain_frames,
)
from schemas.errors import SpecError
from schemas.names import shorten
from schemas.objects import object_category
from schemas.scene import PALM_HOVER

#: Joint angles at the end of each finger's synergy (thumb, index, middle, ring, little).
SYNERGY_END = np.array(
    [
        [1.00, 0.80, 1.00],
        [1.45, 1.60, 1.10],
        [1.45, 1.60, 1.10],
        [1.45, 1.60, 1.10],
        [1.45, 1.60, 1.10],
    ]
)
_GRID = 49
_SAMPLES_PER_SEGMENT = 4


def _finger_clearance(palm_pose: np.ndarray, closure: np.ndarray, category: str, size: float, side: str) -> np.ndarray:
    """(len(closure), 5) clearance of each finger's capsules at each closure fraction."""
    cat = object_category(category)
    q = REST_JOINTS + closure[:, None] * (SYNERGY_END.reshape(15) - REST_JOINTS)
    pos, _ = chain_frames(np.repeat(palm_pose[None], len(closure), axis=0), q, side)
    w = np.linspace(0.0, 1.0, _SAMPLES_PER_SEGMENT, endpoint=False)
    starts, ends = pos[:, :, :3], pos[:, :, 1:]
    points = starts[:, :, :, None] + w[:, None] * (ends - starts)[:, :, :, None]
    points = np.concatenate([points.reshape(len(closure), 5, -1, 3), pos[:, :, 3:]], axis=2)
    centre = np.array([0.0, cat.half_height(size), 0.0])
    axis = cat.geometry.axis(cat.lying)  # world axis of a cylinder in the canonical placement
    dist = signed_distance_local(points - centre, cat.shape, cat.scaled_dims(size), axis)
    return dist.min(axis=-1) - FINGER_RADII


@functools.lru_cache(maxsize=4096)
def _grasp_angles(category: str, size: float, side: str) -> tuple[float, ...]:
    cat = object_category(category)
    top = 2.0 * cat.half_height(size)
    palm = np.array([0.0, top + PALM_HOVER, 0.0, 0.0, 0.0, 0.0])
    grid = np.linspace(0.0, 1.0, _GRID)
    clearance = _finger_clearance(palm, grid, category, size, side)
    closure = np.ones(5)
    for f in range(5):
        hit = np.flatnonzero(clearance[:, f] <= 0.0)
        if len(hit) == 0:
            continue
        k = hit[0]
        if k == 0:
            closure[f] = 0.0
            continue
        c0, c1 = clearance[k - 1, f], clearance[k, f]
        closure[f] = grid[k - 1] + (grid[k] - grid[k - 1]) * c0 / (c0 - c1)
    angles = REST_JOINTS + (closure[:, None] * (SYNERGY_END - REST_JOINTS.reshape(5, 3))).reshape(15)
    return tuple(float(a) for a in np.clip(angles, JOINT_LOWER, JOINT_UPPER))


@functools.lru_cache(maxsize=4096)
def _lowest_offset(category: str, size: float, side: str) -> float:
    grasp = np.array(_grasp_angles(category, size, side))
    closure = np.linspace(0.0, 1.0, 21)[:, None]
    joints = REST_JOINTS + closure * (grasp - REST_JOINTS)
    palm = np.zeros((len(closure), 6))
    return float(chain_frames(palm, joints, side)[0][:, :, 3, 1].min())


def lowest_fingertip_offset(category: str, size: float, side: str) -> float:
    """Lowest fingertip height relative to the palm centre (palm down) while the fingers
    close from rest to :func:`grasp_angles` (the synergy sampled at 21 fractions)."""
    _check(category, size, side)
    return _lowest_offset(category, float(size), side)


def _check(category: str, size: float, side: str) -> None:
    """Validate before the caches, which would raise TypeError on unhashable arguments."""
    if not isinstance(category, str):
        raise SpecError(f"object must be a category name, got {shorten(repr(category))}")
    object_category(category)
    if not isinstance(side, str) or side not in SIDES:
        raise SpecError(f"hand side must be one of {list(SIDES)}, got {shorten(repr(side))}")
    if isinstance(size, bool) or not isinstance(size, numbers.Real) or not math.isfinite(size) or size <= 0:
        raise SpecError(f"object size must be a finite number > 0, got {shorten(repr(size))}")


def grasp_angles(category: str, size: float, side: str) -> np.ndarray:
    """(15,) ground-truth joint angles (radians) grasping ``category`` of ``size`` with the ``side`` hand."""
    _check(category, size, side)
    return np.array(_grasp_angles(category, float(size), side))
