"""How much of the object the camera sees: an analytic screen-space test against the hand.

The observe-before-act protocol (paper 3.3) shows the model the target's motion before
it acts, so an episode is fair only if the object is in the image and not hidden by
the resting hand while it is observed. This module answers that without rendering:

* Every shape involved is convex (the object's sphere, cylinder or box; the palm box;
  the wrist cylinder; each finger segment, a capsule), so each one's silhouette is the
  convex hull of its projected surface points. Silhouettes are filled at
  :data:`SUPERSAMPLE` x the image resolution and counted.
* A hand part hides the object where their silhouettes overlap if the part is nearer
  the camera. A part that is neither wholly nearer nor wholly farther counts as
  nearer, so the test errs toward calling the object hidden.
* Obstacles (:class:`schemas.obstacles.Obstacle`, boxes) hide the object where their
  silhouettes (the hull of a box's 8 projected corners, exact) overlap and the obstacle
  is in front. An obstacle and an object that do not touch are separated by a plane,
  so one of them is in front wherever they overlap: the obstacle, unless the object
  meets the cone from the camera to the box but not the box itself (an object touching
  or inside an obstacle counts as hidden by it). Rays through the object's points
  settle that in nearly every case; a linear program settles the rest.
* The *visible fraction* of a frame is the object's silhouette area inside the image
  and not hidden, over its whole silhouette area.

A cheap exact shortcut decides nearly every frame: the camera has no roll, so a table
line of constant Z projects to one image row, and any point at height >= 0 that lies
beyond that line projects above that row. An object whose footprint starts beyond
the Z where the rest hand's silhouette ends (:func:`rest_shadow_z`) can never be
hidden by the resting hand. The recipe's feasibility filter uses that bound
(:func:`generators.grids.feasible`); the renderer's segmentation masks are the ground
truth the tests and ``benchmarks/visibility.py`` check both against.
"""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np

from generators.camera import points_in_view, project
from generators.clearance import checked_obstacles, obstacle_centre, obstacle_corners, obstacle_rotation
from generators.hand import (
    DEFAULT_GEOMETRY,
    FINGER_RADII,
    PALM_HALF_EXTENTS,
    REST_JOINTS,
    REST_PALM,
    SIDES,
    WRIST_OFFSET,
    HandGeometry,
    chain_frames,
)
from schemas.objects import object_category
from schemas.obstacles import Obstacle
from schemas.rotations import euler_to_matrix, quaternion_to_matrix
from schemas.scene import CAMERA_EYE, CAMERA_NEAR, DEFAULT_RESOLUTION, MIN_OBSERVE_VISIBLE
from schemas.shapes.base import BOX_SIGNS, UNIT_SPHERE, rim

#: Sub-pixels per pixel side when filling silhouettes.
SUPERSAMPLE = 4
#: Fixed-point bits of the vertex coordinates given to ``cv2.fillConvexPoly``.
_SHIFT = 4
#: The wrist cylinder drawn behind the palm (generators.hand_urdf): radius factor, length.
_WRIST_RADIUS_FACTOR = 0.7
_WRIST_LENGTH = 0.5


#: A sampled sphere's hull lies inside the sphere; occluders are grown by this factor so
#: that their hulls contain the true shape (the lattice's largest gap is under 0.3 rad).
_OCCLUDER_GROWTH = 1.05


def _object_local_points(category: str, size: float) -> np.ndarray:
    """(k, 3) points in the object's frame whose convex hull is the object."""
    cat = object_category(category)
    return cat.geometry.hull_points(cat.scaled_dims(size), cat.lying)


def object_surface_points(category: str, size: float, poses: np.ndarray) -> np.ndarray:
    """(..., k, 3) world points whose convex hull is the object at each pose (..., 7)
    (x, y, z, qx, qy, qz, qw)."""
    poses = np.asarray(poses, dtype=np.float64)
    rot = quaternion_to_matrix(poses[..., 3:7].reshape(-1, 4)).reshape(poses.shape[:-1] + (3, 3))
    local = _object_local_points(category, size)
    return poses[..., None, :3] + np.einsum("...ij,kj->...ki", rot, local)


def hand_parts(palm_pose: np.ndarray, joint_angles: np.ndarray, side: str,
               geometry: HandGeometry = DEFAULT_GEOMETRY) -> list[np.ndarray]:
    """The hand's convex parts at one pose, each as (k, 3) world points whose hull contains it:
    the palm box, the wrist cylinder, and one capsule per finger segment."""
    palm = np.asarray(palm_pose, dtype=np.float64)
    rot = euler_to_matrix(palm[None, 3:])[0]
    parts = [palm[:3] + (BOX_SIGNS * np.asarray(PALM_HALF_EXTENTS)) @ rot.T]
    axis = rot[:, 2]
    wrist = palm[:3] + rot @ np.asarray(WRIST_OFFSET)
    radius = _OCCLUDER_GROWTH * _WRIST_RADIUS_FACTOR * PALM_HALF_EXTENTS[0]
    parts.append(np.concatenate([rim(wrist, axis, radius), rim(wrist - _WRIST_LENGTH * axis, axis, radius)]))
    positions, _ = chain_frames(palm[None], np.asarray(joint_angles, dtype=np.float64)[None], side, geometry)
    for finger in range(5):
        ball = _OCCLUDER_GROWTH * FINGER_RADII[finger] * UNIT_SPHERE
        chain = positions[0, finger]
        for k in range(3):
            parts.append(np.concatenate([chain[k] + ball, chain[k + 1] + ball]))
    return parts


def _fill(mask: np.ndarray, pixels: np.ndarray, origin: np.ndarray) -> None:
    """Fill the convex hull of ``pixels`` (k, 2) (image pixels) into the supersampled ``mask``."""
    local = (pixels - origin) * SUPERSAMPLE * (1 << _SHIFT)
    hull = cv2.convexHull(np.round(local).astype(np.int32))
    cv2.fillConvexPoly(mask, hull, 1, lineType=cv2.LINE_8, shift=_SHIFT)


def _hulls_meet(points: np.ndarray, others: np.ndarray) -> bool:
    """Whether the convex hulls of two point sets (k, 3) and (j, 3) share a point (a
    feasibility linear program: one point as a convex combination of each set)."""
    from scipy.optimize import linprog

    k, j = len(points), len(others)
    equalities = np.zeros((5, k + j))
    equalities[0, :k] = 1.0
    equalities[1, k:] = 1.0
    equalities[2:, :k] = points.T
    equalities[2:, k:] = -others.T
    result = linprog(np.zeros(k + j), A_eq=equalities, b_eq=[1.0, 1.0, 0.0, 0.0, 0.0], bounds=(0.0, None), method="highs")
    return result.status == 0


def _box_apart(points: np.ndarray, obstacle: Obstacle) -> bool:
    """Whether the hull of ``points`` (k, 3) and the obstacle box do not meet."""
    local = (points - obstacle_centre(obstacle)) @ obstacle_rotation(obstacle)
    half = np.asarray(obstacle.half_extents)
    if np.any(np.all(local > half, axis=0) | np.all(local < -half, axis=0)):
        return True
    return not _hulls_meet(points, obstacle_corners(obstacle))


def obstacle_hides(object_points: np.ndarray, obstacle: Obstacle) -> bool:
    """Whether the obstacle is in front of the object (hull of ``object_points`` (k, 3))
    wherever their silhouettes overlap (see the module's docstring)."""
    eye = np.asarray(CAMERA_EYE, dtype=np.float64)
    points = np.asarray(object_points, dtype=np.float64)
    rot, half = obstacle_rotation(obstacle), np.asarray(obstacle.half_extents)
    rays = np.concatenate([points, points.mean(axis=0, keepdims=True)])
    start = (eye - obstacle_centre(obstacle)) @ rot
    step = (rays - eye) @ rot  # ray(t) = eye + t (x - eye): the object's point at t = 1
    with np.errstate(divide="ignore", invalid="ignore"):
        near, far = (-half - start) / step, (half - start) / step
    flat = step == 0.0
    inside = np.abs(start) <= half
    enter = np.where(flat, np.where(inside, -np.inf, np.inf), np.fmin(near, far)).max(axis=1)
    leave = np.where(flat, np.where(inside, np.inf, -np.inf), np.fmax(near, far)).min(axis=1)
    hit = (enter <= leave) & (leave >= 0.0)
    if np.any(hit & (enter <= 1.0)):
        return True
    if np.any(hit):
        return not _box_apart(points, obstacle)
    corners = obstacle_corners(obstacle)
    return not (_hulls_meet(points, np.concatenate([corners, eye[None]])) and _box_apart(points, obstacle))


def visible_fraction(
    object_points: np.ndarray,
    occluders: list[np.ndarray],
    resolution: int = DEFAULT_RESOLUTION,
    obstacles: tuple[Obstacle, ...] = (),
) -> float:
    """Share of the object's silhouette (hull of ``object_points``) that lies inside the
    square image and is not covered by a nearer occluder (hulls of ``occluders``) or by
    an obstacle in front of it (:func:`obstacle_hides`)."""
    obj_px, obj_depth = project(object_points, resolution, resolution)
    if np.any(obj_depth <= CAMERA_NEAR):  # cut by the near plane, never drawn whole; and its
        return 0.0  # silhouette, rasterized below, grows without bound as the depth nears 0
    low = np.floor(obj_px.min(axis=0)) - 1.0
    high = np.ceil(obj_px.max(axis=0)) + 1.0
    shape = tuple(int(v) for v in ((high - low)[::-1] * SUPERSAMPLE))
    silhouette = np.zeros(shape, dtype=np.uint8)
    _fill(silhouette, obj_px, low)
    total = int(silhouette.sum())
    if total == 0:
        return 0.0
    visible = silhouette.copy()
    rows = (np.arange(shape[0]) + 0.5) / SUPERSAMPLE + low[1]
    cols = (np.arange(shape[1]) + 0.5) / SUPERSAMPLE + low[0]
    visible[(rows < 0) | (rows >= resolution), :] = 0
    visible[:, (cols < 0) | (cols >= resolution)] = 0
    farthest = float(obj_depth.max())
    for part in occluders:
        part_px, part_depth = project(part, resolution, resolution)
        if float(part_depth.min()) > farthest:
            continue
        if np.any(part_px.max(axis=0) < low) or np.any(part_px.min(axis=0) > high):
            continue
        cover = np.zeros(shape, dtype=np.uint8)
        _fill(cover, part_px, low)
        visible[cover > 0] = 0
    nearest = float(obj_depth.min())
    for obstacle in checked_obstacles(obstacles):
        box_px, box_depth = project(obstacle_corners(obstacle), resolution, resolution)
        if float(box_depth.min()) > farthest:
            continue
        if float(box_depth.min()) <= 0.0:  # reaches behind the camera: its silhouette has no hull
            cover = np.ones(shape, dtype=np.uint8)
        elif np.any(box_px.max(axis=0) < low) or np.any(box_px.min(axis=0) > high):
            continue
        else:
            cover = np.zeros(shape, dtype=np.uint8)
            _fill(cover, box_px, low)
        if not np.any(cover & visible):
            continue
        if float(box_depth.max()) < nearest or obstacle_hides(object_points, obstacle):
            visible[cover > 0] = 0
    return int(visible.sum()) / total


@cache
def _rest_parts(side: str, geometry: HandGeometry = DEFAULT_GEOMETRY) -> tuple[np.ndarray, ...]:
    return tuple(hand_parts(REST_PALM, REST_JOINTS, side, geometry))


@cache
def rest_shadow_z(geometry: HandGeometry = DEFAULT_GEOMETRY) -> float:
    """The farthest table Z that any ray from the camera through the resting hand (either
    side) reaches: objects whose footprint lies wholly beyond it are never hidden by it."""
    eye = np.asarray(CAMERA_EYE, dtype=np.float64)
    points = np.concatenate([part for side in SIDES for part in _rest_parts(side, geometry)])
    reach = eye[1] / (eye[1] - points[:, 1])
    return float((eye[2] + reach * (points[:, 2] - eye[2])).max())


def _footprint_near_z(category: str, size: float, poses: np.ndarray) -> np.ndarray:
    """(n,) the nearest table Z of each pose's object (its centre Z minus its reach)."""
    cat = object_category(category)
    reach = cat.geometry.reach(cat.scaled_dims(size), cat.lying, np.hypot)
    return np.asarray(poses, dtype=np.float64)[:, 2] - reach


def _clear_of_obstacles(points: np.ndarray, obstacles: tuple[Obstacle, ...], resolution: int) -> np.ndarray:
    """(n,) whether no obstacle's silhouette box meets the object's at each pose (points
    (n, k, 3)): such a pose cannot be hidden by any of them."""
    clear = np.ones(len(points), dtype=bool)
    if not obstacles:
        return clear
    px, _ = project(points, resolution, resolution)
    low, high = px.min(axis=1), px.max(axis=1)
    for obstacle in obstacles:
        box_px, box_depth = project(obstacle_corners(obstacle), resolution, resolution)
        apart = np.any((high < box_px.min(axis=0)) | (low > box_px.max(axis=0)), axis=1)
        clear &= apart & bool(box_depth.min() > 0.0)
    return clear


def observe_visibility(
    category: str,
    size: float,
    side: str,
    poses: np.ndarray,
    resolution: int = DEFAULT_RESOLUTION,
    obstacles: tuple[Obstacle, ...] = (),
    geometry: HandGeometry = DEFAULT_GEOMETRY,
) -> np.ndarray:
    """(n,) visible fraction of the object at each pose (n, 7) with the hand (of ``geometry``)
    at rest among ``obstacles``.

    A pose whose object is wholly in view, wholly beyond :func:`rest_shadow_z` and clear
    of every obstacle's silhouette is 1.0 without filling anything; the rest are
    measured by :func:`visible_fraction`.
    """
    poses = np.asarray(poses, dtype=np.float64)
    obstacles = checked_obstacles(obstacles)
    out = np.ones(len(poses))
    points = object_surface_points(category, size, poses)
    clear = _footprint_near_z(category, size, poses) > rest_shadow_z(geometry)
    clear &= points_in_view(points).all(axis=-1)
    clear &= _clear_of_obstacles(points, obstacles, resolution)
    occluders = list(_rest_parts(side, geometry))
    for k in np.flatnonzero(~clear):
        out[k] = visible_fraction(object_surface_points(category, size, poses[k]), occluders, resolution, obstacles)
    return out


def first_hidden_frame(
    category: str, size: float, side: str, poses: np.ndarray, obstacles: tuple[Obstacle, ...] = (),
    geometry: HandGeometry = DEFAULT_GEOMETRY,
) -> tuple[int, float] | None:
    """The first pose whose object is less than :data:`MIN_OBSERVE_VISIBLE` visible with the
    hand at rest (and ``obstacles``), with its visible fraction, or None when every pose
    shows enough of it."""
    fractions = observe_visibility(category, size, side, poses, obstacles=obstacles, geometry=geometry)
    hidden = np.flatnonzero(fractions < MIN_OBSERVE_VISIBLE)
    if len(hidden) == 0:
        return None
    k = int(hidden[0])
    return k, float(fractions[k])
