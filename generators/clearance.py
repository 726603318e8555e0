"""Clearance between obstacles and the hand or the target object: exact distances to boxes.

An obstacle (:class:`schemas.obstacles.Obstacle`) is a box whose centre is
``(x, hy, z)`` and whose frame is turned by ``yaw`` about +Y with the right-handed
rotation the rest of the code uses, ``R = Ry(yaw) = euler_to_matrix((0, yaw, 0))``
(the quaternion ``(0, sin(yaw/2), 0, cos(yaw/2))`` pybullet is given): a positive yaw
turns the box's +X toward world -Z and its +Z toward world +X.

Every shape measured here is convex: the obstacle boxes; the palm box, the wrist
cylinder and the fifteen finger capsules of :mod:`generators.hand_urdf`; the object's
sphere, cylinder or box (:mod:`schemas.objects`). Distances between them reduce to
minima of a convex signed distance along segments, over segments chosen so that the
smallest of those minima is the distance:

* capsule and box: the capsule's axis, less its radius; sphere and box: the centre.
* box and box: the edges of each against the other. The closest pair of two disjoint
  polytopes can always be taken with a point on an edge of one of them, and two
  overlapping boxes always have an edge of one meeting the other.
* cylinder and box: the box's edges against the cylinder, and for each box face the
  cylinder's generator through its support point toward that face (the closest pair
  has the box point on an edge or inside a face). Overlaps are caught exactly by the
  cylinder's axis and the distance from the axis to the box cut to the cylinder's slab.

Most segments are settled by their ends (a distance rising from a segment's start has
its minimum there) or ruled out by bounds; the rest are bisected on the sign of the
slope, :data:`BISECTIONS` times, which places the minimum within ``2**-27`` of the
segment's length: values are exact to 1e-7 units (the longest edge, 12 units) and to
4e-9 units for the hand's own parts. Values above zero are distances; zero or below
means touching or overlapping (the magnitude then grows with the overlap but is not an
exact penetration depth).

Geometry: finger tips are drawn as spheres 0.999 times the finger's radius, so taking
the whole capsule underestimates clearance there by at most 1e-4 units. The mug's
handle is not part of its category's shape (a cylinder) and is not measured; nor are
the markings, which stand out of an object's surface by a few hundredths of its size.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from generators.hand import DEFAULT_GEOMETRY, FINGER_RADII, PALM_HALF_EXTENTS, WRIST_OFFSET, HandGeometry, chain_frames
from schemas.errors import SpecError
from schemas.objects import object_category
from schemas.obstacles import Obstacle
from schemas.rotations import euler_to_matrix, quaternion_to_matrix

#: The wrist cylinder of :mod:`generators.hand_urdf`: radius, and length behind the wrist point.
WRIST_RADIUS = 0.7 * PALM_HALF_EXTENTS[0]
WRIST_LENGTH = 0.5
#: Bisection steps along a segment: its minimum is placed within 2**-27 of its length.
BISECTIONS = 26

_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
#: A box's 12 edges: start corners (signs of the half extents) and vectors (multiples of them).
_EDGE_STARTS = np.array(
    [np.roll([-1.0, a, b], axis) for axis in range(3) for a in (-1.0, 1.0) for b in (-1.0, 1.0)]
)
_EDGE_VECTORS = np.repeat(2.0 * np.eye(3), 4, axis=0)
_FACE_NORMALS = np.concatenate([np.eye(3), -np.eye(3)])
_PAIRS = np.array([(i, j) for i in range(12) for j in range(i + 1, 12)])


# obstacles ------------------------------------------------------------------------
def checked_obstacles(obstacles) -> tuple[Obstacle, ...]:
    """``obstacles`` as a tuple, after checking that each one is an :class:`Obstacle`."""
    if isinstance(obstacles, Obstacle) or not isinstance(obstacles, Sequence):
        raise SpecError(f"obstacles must be a sequence of Obstacle, got {type(obstacles).__name__}")
    for k, o in enumerate(obstacles):
        if not isinstance(o, Obstacle):
            raise SpecError(f"obstacles[{k}] must be an Obstacle, got {type(o).__name__}")
    return tuple(obstacles)


def obstacle_rotation(obstacle: Obstacle) -> np.ndarray:
    """(3, 3) rotation of the obstacle's frame, ``Ry(yaw)`` (columns: its axes in the world)."""
    return euler_to_matrix(np.array([0.0, obstacle.yaw, 0.0]))


def obstacle_centre(obstacle: Obstacle) -> np.ndarray:
    """(3,) the box's centre: its footprint centre, half its height above the table."""
    return np.array(obstacle.position)


def obstacle_frames(obstacles: Sequence[Obstacle]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (m, 3), rotations (m, 3, 3) and half extents (m, 3) of the obstacles."""
    obstacles = checked_obstacles(obstacles)
    if not obstacles:
        return np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3))
    return (
        np.stack([obstacle_centre(o) for o in obstacles]),
        np.stack([obstacle_rotation(o) for o in obstacles]),
        np.array([o.half_extents for o in obstacles], dtype=np.float64),
    )


def obstacle_corners(obstacle: Obstacle) -> np.ndarray:
    """(8, 3) world corners of the obstacle box."""
    return obstacle_centre(obstacle) + (_SIGNS * np.asarray(obstacle.half_extents)) @ obstacle_rotation(obstacle).T


# signed distances in a shape's own frame, coordinates first: p (3, ...) -------------
def _box_sd(p: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Signed distance to a centred box of half extents ``half`` (3, ...)."""
    q = np.abs(p) - half
    out = np.maximum(q, 0.0)
    return np.sqrt((out * out).sum(axis=0)) + np.minimum(q.max(axis=0), 0.0)


def _box_rising(p: np.ndarray, d: np.ndarray, half: np.ndarray) -> np.ndarray:
    """A value of the sign of :func:`_box_sd`'s derivative at points ``p`` (3, k) along ``d``
    (inside the box, where it has no gradient, its derivative along a subgradient)."""
    q = np.abs(p) - half
    rate = np.sign(p) * d
    outside = (np.maximum(q, 0.0) * rate).sum(axis=0)
    return np.where((q > 0.0).any(axis=0), outside, rate[q.argmax(axis=0), np.arange(p.shape[1])])


def _box_sd_slope(p: np.ndarray, d: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_box_sd` at points ``p`` (3, k) and its derivative along ``d`` (as above)."""
    q = np.abs(p) - half
    out = np.maximum(q, 0.0)
    norm = np.sqrt((out * out).sum(axis=0))
    rate = np.sign(p) * d
    outside = np.divide((out * rate).sum(axis=0), norm, out=np.zeros_like(norm), where=norm > 0.0)
    slope = np.where((q > 0.0).any(axis=0), outside, rate[q.argmax(axis=0), np.arange(p.shape[1])])
    return norm + np.minimum(q.max(axis=0), 0.0), slope


def _cylinder_sd(p: np.ndarray, dims: np.ndarray) -> np.ndarray:
    """Signed distance to a centred cylinder along local Z, ``dims`` (2, ...) = (radius, half length)."""
    d1 = np.hypot(p[0], p[1]) - dims[0]
    d2 = np.abs(p[2]) - dims[1]
    return np.hypot(np.maximum(d1, 0.0), np.maximum(d2, 0.0)) + np.minimum(np.maximum(d1, d2), 0.0)


def _cylinder_parts(p: np.ndarray, d: np.ndarray, dims: np.ndarray):
    rho = np.hypot(p[0], p[1])
    d1 = rho - dims[0]
    d2 = np.abs(p[2]) - dims[1]
    radial = np.divide(p[0] * d[0] + p[1] * d[1], rho, out=np.zeros_like(rho), where=rho > 0.0)
    axial = np.sign(p[2]) * d[2]
    return d1, d2, radial, axial, np.maximum(d1, 0.0), np.maximum(d2, 0.0)


def _cylinder_rising(p: np.ndarray, d: np.ndarray, dims: np.ndarray) -> np.ndarray:
    """As :func:`_box_rising`, for :func:`_cylinder_sd`."""
    d1, d2, radial, axial, e1, e2 = _cylinder_parts(p, d, dims)
    return np.where((d1 > 0.0) | (d2 > 0.0), e1 * radial + e2 * axial, np.where(d1 >= d2, radial, axial))


def _cylinder_sd_slope(p: np.ndarray, d: np.ndarray, dims: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """As :func:`_box_sd_slope`, for :func:`_cylinder_sd`."""
    d1, d2, radial, axial, e1, e2 = _cylinder_parts(p, d, dims)
    norm = np.hypot(e1, e2)
    outside = np.divide(e1 * radial + e2 * axial, norm, out=np.zeros_like(norm), where=norm > 0.0)
    slope = np.where((d1 > 0.0) | (d2 > 0.0), outside, np.where(d1 >= d2, radial, axial))
    return norm + np.minimum(np.maximum(d1, d2), 0.0), slope


#: Per shape: signed distance, the sign of its slope, both it and its slope.
_SHAPES = {
    "box": (_box_sd, _box_rising, _box_sd_slope),
    "cylinder": (_cylinder_sd, _cylinder_rising, _cylinder_sd_slope),
}


def _segment_minimum(kind: str, a: np.ndarray, d: np.ndarray, dims: np.ndarray) -> np.ndarray:
    """(k,) min over t in [0, 1] of the shape's signed distance at ``a + t d`` (a, d (3, k);
    dims (w, k)), by bisection on the sign of its slope: it is convex along the segment."""
    sd, rising, _ = _SHAPES[kind]
    t = np.zeros(a.shape[1])
    step = 1.0
    for _ in range(BISECTIONS):
        step *= 0.5
        t += step * (rising(a + (t + step) * d, d, dims) <= 0.0)
    return sd(a + (t + 0.5 * step) * d, dims)


def box_signed_distance(points: np.ndarray, obstacle: Obstacle) -> np.ndarray:
    """Exact signed distance (...,) from world points (..., 3) to the obstacle box's surface:
    positive outside, negative inside."""
    if not isinstance(obstacle, Obstacle):
        raise SpecError(f"obstacle must be an Obstacle, got {type(obstacle).__name__}")
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 0 or pts.shape[-1] != 3:
        raise SpecError(f"points must have shape (..., 3), got {pts.shape}")
    local = np.moveaxis((pts - obstacle_centre(obstacle)) @ obstacle_rotation(obstacle), -1, 0)
    half = np.asarray(obstacle.half_extents, dtype=np.float64).reshape((3,) + (1,) * (pts.ndim - 1))
    return _box_sd(local, half)


# segments against convex shapes, grouped per (frame, obstacle) -----------------------
def _local(x: np.ndarray, centre: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """World points (..., k, 3) in a frame (centre (..., 3), rotation (..., 3, 3))."""
    return (x - centre[..., None, :]) @ rot


def _local_vectors(v: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """World vectors (..., k, 3) in a frame of rotation (..., 3, 3)."""
    return v @ rot


def _rotate(v: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Frame vectors (..., k, 3) in the world (``rot @ v`` per row)."""
    return v @ np.swapaxes(rot, -1, -2)


def _box_edges(centre: np.ndarray, rot: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World starts and vectors (..., 12, 3) of the box's edges."""
    starts = centre[..., None, :] + _rotate(_EDGE_STARTS * half[..., None, :], rot)
    return starts, _rotate(_EDGE_VECTORS * half[..., None, :], rot)


class _Rows:
    """Segments along which to minimise a shape's signed distance, grouped per (frame,
    obstacle), and exact checks; :meth:`minimum` is the smallest value of each group."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = shape
        self.segments: dict[str, list[tuple[np.ndarray, ...]]] = {kind: [] for kind in _SHAPES}
        self.checks: list[tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]] = []

    def add(self, kind: str, a, d, dims, offset=0.0) -> None:
        """Segment starts ``a`` and vectors ``d`` (n, m, k, 3) in the shape's frame, its
        dimensions ``dims`` (..., w) and an offset to subtract (a radius), broadcast."""
        full = self.shape + (np.shape(a)[-2],)

        def rows(v: np.ndarray) -> np.ndarray:
            v = np.broadcast_to(v, full + (np.shape(v)[-1],))
            return np.moveaxis(v, -1, 0).reshape(v.shape[-1], full[0] * full[1], full[2])

        offset = np.broadcast_to(offset, full).reshape(full[0] * full[1], full[2])
        self.segments[kind].append((rows(a), rows(d), rows(dims), offset))

    def check(self, near: np.ndarray, value: Callable[[np.ndarray], np.ndarray]) -> None:
        """``value(mask)``: exact values for the groups of a (n, m) mask, wanted only where
        ``near`` holds and the segments leave a positive minimum."""
        self.checks.append((np.broadcast_to(near, self.shape), value))

    def minimum(self) -> np.ndarray:
        """The smallest value of each group.

        Along a segment the signed distance is convex and 1-Lipschitz, so its values and
        slopes at the ends and its midpoint value settle most segments at once: a
        segment rising from its start has its minimum there (falling to its end, there).
        The rest are bounded above by the midpoint and below by the ends' tangents, the
        chords of each half extended over the other, and the mean of each half's end
        values less a quarter of its length; only those that may beat the best value
        seen are searched."""
        groups = self.shape[0] * self.shape[1]
        best = np.full(groups, np.inf)
        found = {}
        for kind, sets in self.segments.items():
            if not sets:
                continue
            a, d, dims = (np.ascontiguousarray(np.concatenate(v, axis=-1).reshape(len(v[0]), -1)) for v in list(zip(*sets))[:3])
            offset = np.concatenate([s[3] for s in sets], axis=-1).reshape(-1)
            sd, _, both = _SHAPES[kind]
            (f0, s0), (f1, s1) = both(a, d, dims), both(a + d, d, dims)
            fm = sd(a + 0.5 * d, dims) - offset
            f0, f1 = f0 - offset, f1 - offset
            quarter = np.sqrt((d * d).sum(axis=0)) / 4.0
            first = np.maximum((f0 + fm) / 2.0 - quarter, np.minimum(fm, 2.0 * fm - f1))
            second = np.maximum((fm + f1) / 2.0 - quarter, np.minimum(fm, 2.0 * fm - f0))
            with np.errstate(divide="ignore", invalid="ignore"):
                cross = np.clip((f1 - s1 - f0) / (s0 - s1), 0.0, 1.0)
            tangents = np.where(s0 < s1, f0 + s0 * cross, -np.inf)
            settled = (s0 >= 0.0) | (s1 <= 0.0)
            upper = np.where(s0 >= 0.0, f0, np.where(s1 <= 0.0, f1, fm))
            lower = np.where(settled, np.inf, np.maximum(np.minimum(first, second), tangents))
            best = np.minimum(best, upper.reshape(groups, -1).min(axis=1))
            found[kind] = (a, d, dims, offset, lower)
        for kind, (a, d, dims, offset, lower) in found.items():
            per = len(lower) // groups
            keep = np.flatnonzero(lower < np.repeat(best, per))
            if len(keep):
                np.minimum.at(best, keep // per, _segment_minimum(kind, a[:, keep], d[:, keep], dims[:, keep]) - offset[keep])
        best = best.reshape(self.shape)
        for near, value in self.checks:
            mask = near & (best > 0.0)
            if mask.any():
                best[mask] = np.minimum(best[mask], value(mask))
        return best


def _origin_to_segments(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Distance from the origin to the 2D segments ``p``-``q`` (2, ...)."""
    e = q - p
    ee = (e * e).sum(axis=0)
    t = np.clip(np.divide(-(p * e).sum(axis=0), ee, out=np.zeros_like(ee), where=ee > 0.0), 0.0, 1.0)
    c = p + t * e
    return np.hypot(c[0], c[1])


def _axis_to_slab_cut(a: np.ndarray, d: np.ndarray, half_length: float) -> np.ndarray:
    """Distance (g,) from a cylinder's axis (local Z) to a box cut to the cylinder's slab
    ``|z| <= half_length``, given the box's edges (3, g, 12) in the cylinder's frame.

    The cut's silhouette along Z is bounded by the edges clipped to the slab and by the
    edges of its sections by the slab's planes (covered by all chords between the points
    where edges cross a plane). Infinite when the cut is empty. An axis that passes through
    the cut is not reported as 0 here: the axis segment's own row finds that overlap."""
    az, dz = a[2], d[2]
    flat = dz == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        crossings = [(s * half_length - az) / dz for s in (-1.0, 1.0)]
    lo = np.where(flat, 0.0, np.maximum(0.0, np.fmin(*crossings)))
    hi = np.where(flat, 1.0, np.minimum(1.0, np.fmax(*crossings)))
    valid = np.where(flat, np.abs(az) <= half_length, lo <= hi)
    clipped = _origin_to_segments(a[:2] + lo * d[:2], a[:2] + hi * d[:2])
    best = np.where(valid, clipped, np.inf).min(axis=-1)
    i, j = _PAIRS[:, 0], _PAIRS[:, 1]
    for t in crossings:
        inside = ~flat & (t >= 0.0) & (t <= 1.0)
        cut = a[:2] + np.where(inside, t, 0.0) * d[:2]
        chords = _origin_to_segments(cut[:, :, i], cut[:, :, j])
        best = np.minimum(best, np.where(inside[:, i] & inside[:, j], chords, np.inf).min(axis=-1))
    return best


def _add_box_box(rows: _Rows, ca, ra, ha, cb, rb, hb) -> None:
    """Rows whose minimum is the distance between boxes A and B (frames broadcast to (n, m))."""
    starts, vecs = _box_edges(ca, ra, ha)
    rows.add("box", _local(starts, cb, rb), _local_vectors(vecs, rb), hb[..., None, :])
    starts, vecs = _box_edges(cb, rb, hb)
    rows.add("box", _local(starts, ca, ra), _local_vectors(vecs, ra), ha[..., None, :])


def _add_cylinder_box(rows: _Rows, cc, rc, radius: float, half_length: float, cb, rb, hb) -> None:
    """Rows whose minimum is the distance between a cylinder (centre, frame with its axis as
    the third column, radius, half length) and box B."""
    axis = rc[..., :, 2]
    normals = _rotate(_FACE_NORMALS, rb)
    radial = normals - (normals * axis[..., None, :]).sum(axis=-1, keepdims=True) * axis[..., None, :]
    norm = np.linalg.norm(radial, axis=-1, keepdims=True)
    towards = -radius * np.divide(radial, norm, out=np.zeros_like(radial), where=norm > 1e-12)
    starts = np.concatenate([towards, np.zeros_like(towards[..., :1, :])], axis=-2)
    starts = starts + (cc - half_length * axis)[..., None, :]
    vecs = np.broadcast_to(2.0 * half_length * axis[..., None, :], starts.shape)
    rows.add("box", _local(starts, cb, rb), _local_vectors(vecs, rb), hb[..., None, :])
    starts, vecs = _box_edges(cb, rb, hb)
    a, d = _local(starts, cc, rc), _local_vectors(vecs, rc)
    rows.add("cylinder", a, d, np.array([radius, half_length]))
    a, d = (np.moveaxis(np.broadcast_to(v, rows.shape + (12, 3)), -1, 0) for v in (a, d))
    reach = np.hypot(radius, half_length) + np.linalg.norm(hb, axis=-1)
    near = np.linalg.norm(cc - cb, axis=-1) <= reach
    rows.check(near, lambda mask: _axis_to_slab_cut(a[:, mask], d[:, mask], half_length) - radius)


# public -------------------------------------------------------------------------------
def hand_clearances(palm_pose: np.ndarray, joint_angles: np.ndarray, side: str, obstacles,
                    geometry: HandGeometry = DEFAULT_GEOMETRY) -> np.ndarray:
    """(n, m) distance from the hand's surface to each obstacle at each frame (palm box,
    wrist cylinder, finger capsules); <= 0 where they touch or overlap."""
    obstacles = checked_obstacles(obstacles)
    palm = np.atleast_2d(np.asarray(palm_pose, dtype=np.float64))
    positions, _ = chain_frames(palm, joint_angles, side, geometry)
    n, m = palm.shape[0], len(obstacles)
    if m == 0:
        return np.full((n, 0), np.inf)
    oc, orot, oh = obstacle_frames(obstacles)
    oc, orot, oh = oc[None], orot[None], oh[None]
    pc, prot = palm[:, None, :3], euler_to_matrix(palm[:, 3:])[:, None]
    rows = _Rows((n, m))
    starts = positions[:, :, :3].reshape(n, 1, 15, 3)
    vecs = (positions[:, :, 1:] - positions[:, :, :3]).reshape(n, 1, 15, 3)
    rows.add("box", _local(starts, oc, orot), _local_vectors(vecs, orot), oh[..., None, :], np.repeat(FINGER_RADII, 3))
    _add_box_box(rows, pc, prot, np.asarray(PALM_HALF_EXTENTS)[None, None], oc, orot, oh)
    wrist = pc + prot @ (np.asarray(WRIST_OFFSET) - [0.0, 0.0, WRIST_LENGTH / 2.0])
    _add_cylinder_box(rows, wrist, prot, WRIST_RADIUS, WRIST_LENGTH / 2.0, oc, orot, oh)
    return rows.minimum()


def hand_table_depth(palm_pose: np.ndarray, joint_angles: np.ndarray, side: str,
                     geometry: HandGeometry = DEFAULT_GEOMETRY) -> np.ndarray:
    """(n,) how deep the hand's lowest point is under the table top (the plane Y = 0) at each
    frame, 0 when above: the palm box's lowest corner, the wrist cylinder's lowest point and
    the finger segments as capsules (a bound at least as deep as the hand body's cylinders)."""
    palm = np.atleast_2d(np.asarray(palm_pose, dtype=np.float64))
    positions, _ = chain_frames(palm, joint_angles, side, geometry)
    start, end = positions[:, :, :3], positions[:, :, 1:]
    fingers = (np.minimum(start[..., 1], end[..., 1]) - FINGER_RADII[None, :, None]).min(axis=(1, 2))
    rot = euler_to_matrix(palm[:, 3:])
    box = palm[:, 1] - np.abs(rot[:, 1, :]) @ np.asarray(PALM_HALF_EXTENTS)
    axis = rot[:, 1, 2]  # the wrist cylinder's axis is the palm's Z
    centre = palm[:, 1] + rot[:, 1, :] @ (np.asarray(WRIST_OFFSET) - [0.0, 0.0, WRIST_LENGTH / 2.0])
    wrist = centre - np.abs(axis) * WRIST_LENGTH / 2.0 - WRIST_RADIUS * np.sqrt(np.clip(1.0 - axis**2, 0.0, 1.0))
    return np.maximum(0.0, -np.minimum(np.minimum(fingers, box), wrist))


def palm_sphere_depth(palm_pose: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    """(n,) how deep a sphere of ``radius`` at ``centres`` (n, 3) is in the palm box or the
    wrist cylinder at each frame of ``palm_pose`` (n, 6); 0 when apart (the hand body's
    object rule: the fingers may close into the object, the palm and wrist may not enter it)."""
    palm = np.atleast_2d(np.asarray(palm_pose, dtype=np.float64))
    rot = euler_to_matrix(palm[:, 3:])
    local = np.einsum("nji,nj->ni", rot, np.asarray(centres, dtype=np.float64) - palm[:, :3])
    half = np.asarray(PALM_HALF_EXTENTS)
    box = np.linalg.norm(local - np.clip(local, -half, half), axis=1)
    wrist = local - (np.asarray(WRIST_OFFSET) - [0.0, 0.0, WRIST_LENGTH / 2.0])
    axial = np.maximum(np.abs(wrist[:, 2]) - WRIST_LENGTH / 2.0, 0.0)
    radial = np.maximum(np.hypot(wrist[:, 0], wrist[:, 1]) - WRIST_RADIUS, 0.0)
    return np.maximum(0.0, radius - np.minimum(box, np.hypot(axial, radial)))


def hand_clearance(palm_pose: np.ndarray, joint_angles: np.ndarray, side: str, obstacles,
                   geometry: HandGeometry = DEFAULT_GEOMETRY) -> np.ndarray:
    """(n,) smallest distance from the hand's surface to any obstacle at each frame of
    palm poses (n, 6) and joint angles (n, 15); +inf without obstacles, <= 0 on contact."""
    per = hand_clearances(palm_pose, joint_angles, side, obstacles, geometry)
    return per.min(axis=1) if per.shape[1] else np.full(per.shape[0], np.inf)


def object_clearances(category: str, size: float, poses: np.ndarray, obstacles) -> np.ndarray:
    """(n, m) distance from the object's surface (its category's sphere, cylinder or box at
    ``size``) at each pose (n, 7) (x, y, z, qx, qy, qz, qw) to each obstacle."""
    obstacles = checked_obstacles(obstacles)
    cat = object_category(category)
    dims = cat.scaled_dims(size)
    poses = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    if poses.ndim != 2 or poses.shape[1] != 7:
        raise SpecError(f"poses must have shape (n, 7), got {poses.shape}")
    n, m = poses.shape[0], len(obstacles)
    if m == 0:
        return np.full((n, 0), np.inf)
    oc, orot, oh = (v[None] for v in obstacle_frames(obstacles))
    centre = poses[:, None, :3]
    solid = cat.geometry.solid(dims, cat.lying)
    if solid.kind == "sphere":
        local = np.moveaxis(_local(centre[:, :, None], oc, orot)[:, :, 0], -1, 0)
        return _box_sd(local, np.moveaxis(oh, -1, 0)) - solid.dims[0]
    frame = quaternion_to_matrix(poses[:, 3:])[:, None][..., list(solid.axes)]
    rows = _Rows((n, m))
    if solid.kind == "box":
        _add_box_box(rows, centre, frame, np.asarray(solid.dims)[None, None], oc, orot, oh)
    else:
        _add_cylinder_box(rows, centre, frame, solid.dims[0], solid.dims[1], oc, orot, oh)
    return rows.minimum()


def object_clearance(category: str, size: float, poses: np.ndarray, obstacles) -> np.ndarray:
    """(n,) smallest distance from the object's surface at each pose (n, 7) to any obstacle;
    +inf without obstacles, <= 0 where it touches or overlaps one."""
    per = object_clearances(category, size, poses, obstacles)
    return per.min(axis=1) if per.shape[1] else np.full(per.shape[0], np.inf)
