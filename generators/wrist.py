"""The wrist reflex: the palm's turn about the vertical as part of the hand, not the action.

The action steers the palm's position and the 15 joints (18 numbers, as in the paper); the
palm's heading (its turn about the vertical, the pitch ``palm_pose[4]``) follows this rule
every frame, the same for the ground truth and every policy (docs/concepts/grasp-hold.md,
"The wrist reflex"). From the hand's new state (palm centre, joints) and the object's pose
at that frame:

* the hand is **closing over a lying cylinder** when some joint has gone
  :data:`CLOSING_FRACTION` of its way from rest to the fist (the grasp design's synergy
  end), the object is a lying cylinder, and the palm centre is within :data:`REACH` of
  the cylinder's centre in the horizontal (XZ) plane;
* then the palm turns toward the cylinder's axis heading (:func:`generators.grasp.cylinder_yaw`),
  taken modulo pi nearest its current heading and within a quarter turn of rest
  (:func:`axis_target`), so that the fingers close across the axis; otherwise it turns
  back toward rest (heading 0);
* at most :data:`WRIST_MAX_SPEED` rad/s, i.e. ``WRIST_MAX_SPEED / FPS`` rad a frame.

Every heading is kept as float32, as the state is recorded, so the planner and a body that
steps the recorded actions compute the same headings bit for bit.

:func:`wrist_clear_heights` is the planner's side: the wrist (the hand body's cylinder
behind the palm, hanging ``WRIST_RADIUS - PALM_HALF_EXTENTS[1]`` = 0.195 under the palm)
lies over a lying cylinder's axis until the palm has turned across it, so the ground
truth keeps the palm high enough for the wrist to clear the object at every frame.
"""

from __future__ import annotations

import math

import numpy as np

from generators.clearance import WRIST_LENGTH, WRIST_RADIUS
from generators.contact import signed_distance
from generators.grasp import cylinder_yaw
from generators.hand import WRIST_OFFSET
from schemas.errors import SpecError
from schemas.objects import object_category
from schemas.scene import LOC_TOLERANCE
from schemas.versions import FPS

#: Fraction of the way from rest to the fist (the design's synergy end) that some joint
#: must pass for the hand to count as closing (3%: the fingers' first flexion; a resting or
#: hovering hand is at 0; on the ground truth's first closing frame, 5.8% of its grasp, the
#: most-closed joint is at 3.6-5.0% of the fist over lying cylinders, so it turns from there).
CLOSING_FRACTION = 0.03
#: How far (units, horizontal) the palm centre may be from a lying cylinder's centre for the
#: reflex: the localisation tolerance (schemas.scene.LOC_TOLERANCE, 3 cm), i.e. only a hand
#: that S_loc counts as over the object turns. The ground truth's palm is over the centre.
REACH = LOC_TOLERANCE
#: Fastest palm turn (rad/s; 10 rad/s = 573 deg/s): a quarter turn in 0.16 s, so the 4
#: frames between the first closing frame and the one the grasp counts as closed cover any
#: turn the reflex asks for (at 7.5 rad/s the ground truth still holds all 108 lying
#: cylinders of test-1k's episodes 0-399, at 5 rad/s 104). Human forearm rotation
#: reaches thousands of deg/s in throwing (Pappas et al., Am. J. Sports Med. 13(4), 1985);
#: 573 deg/s is a fast voluntary turn, below the fingers' JOINT_MAX_SPEED (15 rad/s).
WRIST_MAX_SPEED = 10.0
#: The largest turn from rest (rad): a quarter turn either way.
QUARTER_TURN = math.pi / 2


def closing_fraction(joints: np.ndarray, fist: np.ndarray) -> float:
    """The largest fraction of its way from rest (0) to ``fist`` (15,) any joint has gone (0 at rest)."""
    q = np.asarray(joints, dtype=np.float64)
    end = np.asarray(fist, dtype=np.float64)
    if q.shape != (15,) or end.shape != (15,) or np.any(end <= 0.0):
        raise SpecError(f"wrist: need 15 joint angles and 15 positive fist angles, got {q.shape} and {end.shape}")
    return float(np.max(q / end))


def axis_target(heading: float, axis_yaw: float) -> float:
    """The heading that lays the palm's X axis along an axis at ``axis_yaw``: of
    ``axis_yaw + k pi``, the one nearest ``heading``, clipped to a quarter turn of rest."""
    target = axis_yaw + math.pi * round((heading - axis_yaw) / math.pi)
    return min(QUARTER_TURN, max(-QUARTER_TURN, target))


def wrist_step(heading: float, palm: np.ndarray, joints: np.ndarray, object_pose: np.ndarray, category: str,
               fist: np.ndarray) -> float:
    """The palm's heading at a frame from its ``heading`` (rad) at the frame before and, at
    this frame, the palm centre ``palm`` (xyz), the ``joints`` (15,), the object's
    ``object_pose`` (x, y, z, qx, qy, qz, qw) and ``category``; ``fist``: the design's
    synergy end. Float32-rounded, as recorded."""
    if not math.isfinite(heading) or abs(heading) > QUARTER_TURN + 1e-6:
        raise SpecError(f"wrist: heading must be finite and within a quarter turn, got {heading!r}")
    target = 0.0
    if object_category(category).lying and closing_fraction(joints, fist) >= CLOSING_FRACTION:
        pose = np.asarray(object_pose, dtype=np.float64)
        if math.hypot(float(palm[0]) - float(pose[0]), float(palm[2]) - float(pose[2])) <= REACH:
            target = axis_target(heading, cylinder_yaw(pose[3:7]))
    limit = WRIST_MAX_SPEED / FPS
    return float(np.float32(heading + min(limit, max(-limit, target - heading))))


def wrist_headings(palm: np.ndarray, joints: np.ndarray, object_poses: np.ndarray, category: str,
                   fist: np.ndarray) -> np.ndarray:
    """(n,) the headings :func:`wrist_step` gives a hand through ``palm`` (n, >= 3) and
    ``joints`` (n, 15) with the object at ``object_poses`` (n, 7), starting at rest (0)."""
    n = len(palm)
    out = np.zeros(n)
    for k in range(1, n):
        out[k] = wrist_step(out[k - 1], palm[k], joints[k], object_poses[k], category, fist)
    return out


#: How far outside the object the planner keeps the wrist's sampled surface (units; the
#: hand body allows TOUCH = 0.05 inside, so the samples' spacing, 0.05 along and 0.08
#: around, cannot hide an entry the body refuses).
WRIST_MARGIN = 0.01
#: The highest the planner lifts the palm for the wrist (units): more than the wrist's
#: 0.195 overhang plus the margin.
WRIST_MAX_LIFT = 0.4


def _wrist_surface() -> np.ndarray:
    """(k, 3) points of the wrist cylinder's surface in the palm frame (rest orientation)."""
    angle = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
    along = np.linspace(0.0, WRIST_LENGTH, 11)
    ring = np.stack([WRIST_RADIUS * np.cos(angle), WRIST_RADIUS * np.sin(angle), np.zeros_like(angle)], axis=-1)
    points = ring[None] + np.stack([np.zeros_like(along), np.zeros_like(along), -along], axis=-1)[:, None]
    return points.reshape(-1, 3) + np.asarray(WRIST_OFFSET, dtype=np.float64)


_WRIST_SURFACE = _wrist_surface()


def wrist_clear_heights(palm: np.ndarray, heading: np.ndarray, category: str, size: float,
                        object_poses: np.ndarray) -> np.ndarray:
    """(n,) the lowest palm height (units) at each frame at which the wrist of a palm at
    ``palm`` (n, >= 3: x, z used, y the floor), turned ``heading`` (n,), is
    :data:`WRIST_MARGIN` outside the object at ``object_poses`` (n, 7): ``palm[:, 1]`` where
    it already is, else raised (bisection, 1e-4 units) up to :data:`WRIST_MAX_LIFT`."""
    palm = np.asarray(palm, dtype=np.float64)
    c, s = np.cos(heading), np.sin(heading)
    local = _WRIST_SURFACE
    offset = np.stack([c[:, None] * local[:, 0] + s[:, None] * local[:, 2],
                       np.broadcast_to(local[:, 1], (len(c), len(local))),
                       -s[:, None] * local[:, 0] + c[:, None] * local[:, 2]], axis=-1)  # (n, k, 3)

    poses = np.asarray(object_poses, dtype=np.float64)

    def clear(y: np.ndarray, rows: np.ndarray) -> np.ndarray:
        centre = np.column_stack([palm[rows, 0], y, palm[rows, 2]])
        return signed_distance(centre[:, None] + offset[rows], category, size, poses[rows]).min(axis=1) >= WRIST_MARGIN

    floor = palm[:, 1]
    every = np.arange(len(floor))
    out = floor.copy()
    rows = every[~clear(floor, every)]  # only the frames whose wrist enters the object are raised
    low, high = floor[rows].copy(), floor[rows] + WRIST_MAX_LIFT
    for _ in range(12 if len(rows) else 0):
        mid = 0.5 * (low + high)
        fine = clear(mid, rows)
        high, low = np.where(fine, mid, high), np.where(fine, low, mid)
    out[rows] = high
    return out
