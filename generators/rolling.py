"""The target's orientation: no-slip rolling of spheres and lying cylinders, and its 7-DoF
pose and angular velocity."""

from __future__ import annotations

import math

import numpy as np

from generators.ballistics import elevation
from generators.primitives import Segment
from generators.quadrature import GL3_NODES, GL3_WEIGHTS, node_times, weighted_sum
from generators.segments import along, grid_steps, walk
from generators.tracks import ROLL_STEP_S, ZERO_SPEED, as_times, check_motion, evaluate, sample_motion
from schemas.errors import SpecError
from schemas.motion import Motion
from schemas.names import shorten
from schemas.objects import ObjectCategory, object_category
from schemas.rotations import qaxis, qexp, qmul

_SQRT3 = math.sqrt(3.0)
#: The two Gauss-Legendre nodes on [0, 1] of the 4th-order Magnus step.
_MAGNUS_C = (0.5 - _SQRT3 / 6.0, 0.5 + _SQRT3 / 6.0)
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
#: A lying cylinder's path heading at the identity orientation: its axis (body +X,
#: as :mod:`generators.scene` builds it) lies across travel along Z.
_FIRST_HEADING = math.pi / 2.0

# ------------------------------------------------------------------------ rotations


def _scan(steps: np.ndarray) -> np.ndarray:
    """Cumulative products ``steps[k] * ... * steps[0]`` (later rotations on the left),
    as a log-depth scan whose entry k depends only on steps 0..k."""
    out = steps.copy()
    d = 1
    while d < out.shape[0]:
        out[d:] = qmul(out[d:], out[:-d])
        d *= 2
    return out


def _roll_rate(v: np.ndarray, radius: float) -> np.ndarray:
    """Angular velocity (n, 3) of no-slip rolling: omega = (+Y x v) / r, v = (vx, 0, vz)."""
    w = np.zeros(v.shape[:-1] + (3,))
    w[..., 0] = v[..., 1] / radius
    w[..., 2] = -v[..., 0] / radius
    return w


def _heading_of(v: np.ndarray) -> np.ndarray:
    return np.arctan2(v[..., 1], v[..., 0])


def _branch(angle, near):
    """The value of ``angle`` modulo pi closest to ``near``."""
    return angle + math.pi * np.round((near - angle) / math.pi)


# ------------------------------------------------------------------ rolling sphere


def _sphere_orientation(motion: Motion, radius: float, t: np.ndarray) -> np.ndarray:
    """Orientation of a sphere rolling without slipping, identity at t = 0.

    Exact on straight stretches (one rotation about the fixed axis +Y x u) and on
    constant-curvature stretches (a rotation about +Y composed with one about a fixed
    axis); elsewhere 4th-order Magnus steps of :data:`ROLL_STEP_S`, each an exact
    rotation, so quaternions stay unit and continuous.
    """

    def handler(seg: Segment, times: np.ndarray, q0: np.ndarray):
        if seg.kind == "line":
            pos = sample_motion(motion, np.append(times, seg.t0)).position
            dist = along(pos[:-1] - pos[-1], seg.u)
            axis = np.array([seg.u[1], 0.0, -seg.u[0]])
            q = qmul(qexp(np.outer(dist / radius, axis)), q0)
        elif seg.kind == "arc":
            tau = times - seg.t0
            w0 = seg.speed / radius * np.array([math.sin(seg.heading), 0.0, -math.cos(seg.heading)])
            w0[1] += seg.rate
            q = qmul(qaxis(1, -seg.rate * tau), qmul(qexp(np.outer(tau, w0)), q0))
        else:
            k, steps = grid_steps(seg, times)
            a = seg.t0 + ROLL_STEP_S * np.arange(steps)
            nodes = np.vstack([_IDENTITY, _scan(_magnus(motion, a, np.full(steps, ROLL_STEP_S), radius))])
            ak = seg.t0 + ROLL_STEP_S * k
            q = qmul(_magnus(motion, ak, times - ak, radius), qmul(nodes[k], q0))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        return q, q[-1]

    return walk(motion, t, handler, _IDENTITY, 4)


def _magnus(motion: Motion, a: np.ndarray, h: np.ndarray, radius: float) -> np.ndarray:
    """One 4th-order Magnus step per row: the rotation over ``[a, a + h]`` as a quaternion."""
    g = node_times(a, h, np.array(_MAGNUS_C))
    v = sample_motion(motion, g.reshape(-1)).velocity.reshape(g.shape + (2,))
    w = _roll_rate(v, radius)
    w1, w2 = w[:, 0], w[:, 1]
    hh = h[:, None]
    theta = 0.5 * hh * (w1 + w2) + (_SQRT3 / 12.0) * hh * hh * np.cross(w2, w1)
    return qexp(theta)


# ---------------------------------------------------------- rolling lying cylinder


def _cylinder_state(motion: Motion, radius: float, t: np.ndarray) -> np.ndarray:
    """Columns (psi, s): the axis-normal heading psi (continuous, defined modulo pi by
    the path) and the signed distance s rolled along (cos psi, sin psi).

    Exact on line and arc stretches; elsewhere psi is exact (the velocity's direction,
    unwrapped modulo pi against a grid of :data:`ROLL_STEP_S`) and s is 3-point
    Gauss-Legendre quadrature of the signed speed on that grid (6th order).
    The first branch is the one nearest pi/2 (travel along Z), so that the start pose is
    the identity's nearest; at kinks of the path the heading jumps to the nearest branch.
    """

    def handler(seg: Segment, times: np.ndarray, state):
        prev, s0 = state
        if seg.kind == "line":
            direction = math.atan2(seg.u[1], seg.u[0])
            if prev is None:
                psi = float(_branch(direction, _FIRST_HEADING))
            elif seg.still:
                psi = prev
            else:
                psi = float(_branch(direction, prev))
            pos = sample_motion(motion, np.append(times, seg.t0)).position
            s = s0 + along(pos[:-1] - pos[-1], (math.cos(psi), math.sin(psi)))
            out = np.column_stack([np.full(times.shape, psi), s])
        elif seg.kind == "arc":
            psi0 = float(_branch(seg.heading, _FIRST_HEADING if prev is None else prev))
            sign = 1.0 if round((psi0 - seg.heading) / math.pi) % 2 == 0 else -1.0
            tau = times - seg.t0
            out = np.column_stack([psi0 + seg.rate * tau, s0 + sign * seg.speed * tau])
        else:
            out = _cylinder_general(motion, seg, times, prev, s0)
        return out, (float(out[-1, 0]), float(out[-1, 1]))

    return walk(motion, t, handler, (None, 0.0), 2)


def _cylinder_general(motion: Motion, seg: Segment, times: np.ndarray, prev, s0: float) -> np.ndarray:
    k, steps = grid_steps(seg, times)
    nodes_t = seg.t0 + ROLL_STEP_S * np.arange(steps + 1)
    sample = sample_motion(motion, nodes_t)
    v, acc = sample.velocity, sample.acceleration
    moving = np.hypot(v[:, 0], v[:, 1]) > ZERO_SPEED
    raw = _heading_of(v)
    if not moving[0]:
        if prev is not None:
            raw[0] = prev
        elif math.hypot(*acc[0]) > ZERO_SPEED:
            raw[0] = math.atan2(acc[0, 1], acc[0, 0])
        elif seg.piece is not None:
            raw[0] = seg.piece.primitive.natural_heading(seg.piece, seg.t0 - seg.piece.t0)
        else:
            raw[0] = 0.0
        moving[0] = True
    last_moving = np.maximum.accumulate(np.where(moving, np.arange(raw.size), 0))
    raw = raw[last_moving]
    psi_nodes = 0.5 * np.unwrap(2.0 * raw)
    psi_nodes += math.pi * round(((_FIRST_HEADING if prev is None else prev) - psi_nodes[0]) / math.pi)

    def signed_speed(at: np.ndarray, psi_ref: np.ndarray) -> np.ndarray:
        vel = sample_motion(motion, at.reshape(-1)).velocity.reshape(at.shape + (2,))
        along = vel[..., 0] * np.cos(psi_ref)[:, None] + vel[..., 1] * np.sin(psi_ref)[:, None]
        return np.copysign(np.hypot(vel[..., 0], vel[..., 1]), along)

    a = nodes_t[:-1]
    full = weighted_sum(signed_speed(node_times(a, np.full(steps, ROLL_STEP_S), GL3_NODES), psi_nodes[:-1]), GL3_WEIGHTS) * ROLL_STEP_S
    s_nodes = s0 + np.concatenate([[0.0], np.cumsum(full)])
    ak = seg.t0 + ROLL_STEP_S * k
    h = times - ak
    s = s_nodes[k] + weighted_sum(signed_speed(node_times(ak, h, GL3_NODES), psi_nodes[k]), GL3_WEIGHTS) * h
    vq = sample_motion(motion, times).velocity
    moving_q = np.hypot(vq[:, 0], vq[:, 1]) > ZERO_SPEED
    psi = np.where(moving_q, _branch(_heading_of(vq), psi_nodes[k]), psi_nodes[k])
    return np.column_stack([psi, s])


# ---------------------------------------------------------------------- object pose


def _category(category: ObjectCategory | str) -> ObjectCategory:
    return object_category(category) if isinstance(category, str) else category


def _check_size(category: ObjectCategory, size: float) -> float:
    if not isinstance(category, ObjectCategory):
        raise SpecError(f"not an object category: {category!r}")
    if isinstance(size, bool) or not isinstance(size, (int, float, np.floating)) or not math.isfinite(size) or size <= 0:
        raise SpecError(f"object size must be a finite number > 0, got {shorten(repr(size))}")
    if category.rolling and category.geometry.roll_mode(category.lying) is None:
        raise SpecError(f"object {category.name!r}: a {'lying ' if category.lying else ''}{category.shape} cannot roll")
    return float(size)


def object_orientation(motion: Motion, category: ObjectCategory | str, size: float, t) -> np.ndarray:
    """Unit quaternions ``(n, 4)`` as ``(qx, qy, qz, qw)``, continuous in time.

    Body frames as :mod:`generators.scene` builds them: Y up; a box's half extents along
    body X, Y, Z; an upright cylinder's axis along body Y; a lying cylinder's along body
    X. Non-rolling objects keep the identity. A rolling sphere turns with
    omega = (+Y x v) / r from the identity at t = 0. A lying cylinder is
    ``rot_y(pi/2 - psi) * rot_x(s / r)``: its axis stays horizontal and normal to the path
    (heading psi, from +X toward +Z) and it spins by the signed distance s rolled along
    (cos psi, sin psi) over its radius. ``category`` may be a category or its name.
    """
    category = _category(category)
    size = _check_size(category, size)
    check_motion(motion)
    t = as_times(t)
    if not category.rolling:
        return np.tile(_IDENTITY, (t.shape[0], 1))
    radius = category.rolling_radius(size)
    if category.geometry.roll_mode(category.lying) == "ball":
        return _sphere_orientation(motion, radius, t)
    state = _cylinder_state(motion, radius, t)
    q = qmul(qaxis(1, _FIRST_HEADING - state[:, 0]), qaxis(0, state[:, 1] / radius))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def object_pose(motion: Motion, category: ObjectCategory | str, size: float, t) -> tuple[np.ndarray, np.ndarray]:
    """The target's poses ``(n, 7)`` = x, y, z, qx, qy, qz, qw and world velocities
    ``(n, 3)``; y is the category's resting half height plus the flight's elevation
    (:mod:`generators.ballistics`, 0 on the table). See :func:`object_orientation` for
    the rotation conventions."""

    category = _category(category)
    size = _check_size(category, size)
    check_motion(motion)
    t = as_times(t)
    sample = sample_motion(motion, t)
    n = t.shape[0]
    pose = np.empty((n, 7))
    pose[:, 0] = sample.position[:, 0]
    lift = elevation(motion, t)
    pose[:, 1] = category.half_height(size) + lift.height
    pose[:, 2] = sample.position[:, 1]
    pose[:, 3:] = object_orientation(motion, category, size, t)
    vel = np.zeros((n, 3))
    vel[:, 0], vel[:, 2] = sample.velocity[:, 0], sample.velocity[:, 1]
    vel[:, 1] = lift.velocity
    return pose, vel


def object_angular_velocity(motion: Motion, category: ObjectCategory | str, size: float, t) -> np.ndarray:
    """World angular velocity ``(n, 3)`` matching :func:`object_orientation`, in closed form:
    0 for non-rolling objects; (+Y x v) / r for spheres; for lying cylinders that plus
    the yaw rate -dpsi/dt about +Y (dpsi/dt = (v x a) / |v|^2, 0 when standing still)."""
    category = _category(category)
    size = _check_size(category, size)
    check_motion(motion)
    sample = evaluate(motion, t)
    n = sample.velocity.shape[0]
    if not category.rolling:
        return np.zeros((n, 3))
    v, a = sample.velocity, sample.acceleration
    w = _roll_rate(v, category.rolling_radius(size))
    if category.geometry.roll_mode(category.lying) == "axle":
        speed2 = v[:, 0] ** 2 + v[:, 1] ** 2
        moving = speed2 > ZERO_SPEED**2
        rate = np.zeros(n)
        rate[moving] = (v[moving, 0] * a[moving, 1] - v[moving, 1] * a[moving, 0]) / speed2[moving]
        w[:, 1] = -rate
    return w
