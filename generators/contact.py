"""Distances between the hand and the object: analytic, vectorised over frames.

The object's local frame is the one its pose quaternion ``(qx, qy, qz, qw)`` rotates
into the world, as :mod:`generators.scene` builds the bodies and
:func:`generators.motion.object_orientation` turns them: a sphere of radius ``r``; a
cylinder ``(r, length)`` whose axis is local +Y when upright and local +X when lying;
a box with half extents ``(hx, hy, hz)`` along local X, Y, Z (``schemas.objects``
dims, scaled to the size).
"""

from __future__ import annotations

import numpy as np

from schemas.objects import object_category
from schemas.rotations import quaternion_to_matrix
from schemas.shapes import shape_named


def to_local(points: np.ndarray, object_pose: np.ndarray) -> np.ndarray:
    """World points (n, k, 3) -> the object's local frame, for poses (n, 7)."""
    pose = np.asarray(object_pose, dtype=np.float64)
    rot = quaternion_to_matrix(pose[:, 3:7])
    rel = np.asarray(points, dtype=np.float64) - pose[:, None, :3]
    return np.einsum("nji,nkj->nki", rot, rel)


def cylinder_axis(category: str) -> int:
    """Index of the local axis a category's round shape runs along (0 = X lying, 1 = Y upright)."""
    cat = object_category(category)
    return cat.geometry.axis(cat.lying)


def signed_distance_local(points: np.ndarray, shape: str, dims: tuple[float, ...], axis: int = 2) -> np.ndarray:
    """Signed distance (..., ) of local points (..., 3) to a shape's surface (negative inside),
    :meth:`schemas.shapes.ObjectShape.signed_distance` of the registered ``shape``.

    ``axis`` is the local axis of a cylinder (2 = Z, pybullet's own primitive).
    """
    return shape_named(shape).signed_distance(np.asarray(points, dtype=np.float64), dims, axis)


def signed_distance(points: np.ndarray, category: str, size: float, object_pose: np.ndarray) -> np.ndarray:
    """Signed distance (n, k) of world points (n, k, 3) to the object's surface at poses (n, 7)."""
    cat = object_category(category)
    local = to_local(points, object_pose)
    return signed_distance_local(local, cat.shape, cat.scaled_dims(size), cylinder_axis(category))


def fingertip_distance(fingertips: np.ndarray, category: str, size: float, object_pose: np.ndarray) -> np.ndarray:
    """(n,) minimum over the fingertips (n, 5, 3) of the (unsigned) distance to the object's surface."""
    return np.abs(signed_distance(fingertips, category, size, object_pose)).min(axis=-1)
