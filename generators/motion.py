"""Motion tokens evaluated in closed form: r(t), v(t), a(t), curvature and arc length,
the target's 7-DoF pose with no-slip rolling, and cheap XZ bounds (paper 3.1, A.6).

Semantics are those of :mod:`schemas.motion`: each token runs on local time since its
own start; a later token is translated to begin where the previous one ended; a
clothoid after another token inherits its end position, heading, speed and curvature;
an overlay adds its displacement since its own start on ``[start, end]`` and holds it
after ``end``. At a join the later token's velocity and acceleration apply.

Times are seconds since the motion's start. Negative times raise :class:`SpecError`.
Past the base track's end the last token's closed form is *extrapolated*, not clamped,
so position, velocity and acceleration stay mutually consistent (the recipe always
makes motions long enough; this is only a safety net).

Every function here is pure and deterministic. Path-dependent quantities (a rolling
sphere's orientation on curved paths, a lying cylinder's heading under overlays) are
integrated on a fixed grid of :data:`ROLL_STEP_S` anchored at each segment's start,
so a time's result does not depend on which other times are asked for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import fresnel

from schemas.errors import SpecError
from schemas.motion import ArcToken, ClothoidToken, HarmonicToken, LineToken, Motion, Token, Track
from schemas.objects import ObjectCategory, object_category

#: Speeds at or below this (units/s) count as standing still: no heading, zero curvature.
ZERO_SPEED = 1e-9
#: Substep of the fixed integration grid for path-dependent rolling quantities (s).
ROLL_STEP_S = 1.0 / 400.0

_TWO_PI = 2.0 * math.pi
_SQRT3 = math.sqrt(3.0)
_MAGNUS_C = (0.5 - _SQRT3 / 6.0, 0.5 + _SQRT3 / 6.0)
_GL3_X = np.array([0.5 - math.sqrt(0.15), 0.5, 0.5 + math.sqrt(0.15)])
_GL3_W = np.array([5.0, 8.0, 5.0]) / 18.0
_GL10_X, _GL10_W = np.polynomial.legendre.leggauss(10)
_GL10_X, _GL10_W = 0.5 * (_GL10_X + 1.0), 0.5 * _GL10_W
#: Absolute error budget (units) of the Fresnel form; beyond it clothoids use quadrature.
_FRESNEL_BUDGET = 1e-11
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
#: A lying cylinder's path heading at the identity orientation: its axis (body +X,
#: as :mod:`generators.scene` builds it) lies across travel along Z.
_FIRST_HEADING = math.pi / 2.0


@dataclass(frozen=True)
class MotionSample:
    """Position, velocity and acceleration in the XZ plane, each ``(n, 2)`` float64."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


# ----------------------------------------------------------------------------- pieces


@dataclass(frozen=True)
class _Piece:
    """One token placed on the global clock with absolute parameters.

    ``p`` by kind: L ``(sx, sz, ux, uz, v0, acc)``; A ``(cx, cz, R, w, th0, turn)`` with
    signed angular velocity ``w``; H ``(cx, cz, ex, ez, amp, om, phase, dx, dz)``;
    C ``(sx, sz, h0, V, k0, c)``.
    """

    kind: str
    t0: float
    duration: float
    p: tuple[float, ...]

    def __post_init__(self) -> None:
        # -0.0 == 0.0, so equal motions share cache entries: canonical zeros keep the
        # output independent of which of them was compiled first.
        object.__setattr__(self, "p", tuple(float(x) + 0.0 for x in self.p))
        object.__setattr__(self, "t0", self.t0 + 0.0)


@dataclass(frozen=True)
class _Compiled:
    pieces: tuple[_Piece, ...]
    starts: np.ndarray
    start: float
    end: float
    origin: np.ndarray  # position at the track's start


def _clothoid_integral(h0: float, k0: float, c: float, s: np.ndarray) -> np.ndarray:
    """Complex ``int_0^s exp(i (h0 + k0 x + c x^2 / 2)) dx`` for arc lengths ``s >= 0``."""
    if c == 0.0:
        if k0 == 0.0:
            return s * complex(math.cos(h0), math.sin(h0))
        half = 0.5 * k0 * s
        return s * np.sinc(half / math.pi) * np.exp(1j * (h0 + half))
    lam = math.sqrt(math.pi / abs(c))
    w0 = k0 / (c * lam)
    w1 = w0 + s / lam
    smax = float(s.max()) if s.size else 0.0
    wmax = max(abs(w0), abs(w0 + smax / lam))
    if 2.2e-16 * (lam * (1.0 + wmax) + smax * wmax * wmax) > _FRESNEL_BUDGET:
        return _clothoid_quadrature(h0, k0, c, s)
    s1, c1 = fresnel(w1)
    s0, c0 = fresnel(w0)
    sign = 1.0 if c > 0 else -1.0
    phase = h0 - k0 * k0 / (2.0 * c)
    return lam * complex(math.cos(phase), math.sin(phase)) * ((c1 - c0) + 1j * sign * (s1 - s0))


def _clothoid_quadrature(h0: float, k0: float, c: float, s: np.ndarray) -> np.ndarray:
    """Composite 10-point Gauss-Legendre with at most 0.5 rad of turning per panel
    (error near machine precision); used where the Fresnel form is ill-conditioned
    (a slope tiny against the squared initial curvature)."""
    smax = float(s.max()) if s.size else 0.0
    turning = (abs(k0) + abs(c) * smax) * smax
    panels = max(1, math.ceil(turning / 0.5))
    out = np.empty(s.shape, dtype=np.complex128)
    j = np.arange(panels, dtype=np.float64)[:, None]
    frac = ((j + _GL10_X[None, :]) / panels).ravel()
    weights = np.tile(_GL10_W, panels) / panels
    for lo in range(0, s.size, 256):
        chunk = s[lo : lo + 256]
        x = chunk[:, None] * frac[None, :]
        out[lo : lo + 256] = _weighted(np.exp(1j * (k0 * x + 0.5 * c * x * x)), weights) * chunk
    return out * complex(math.cos(h0), math.sin(h0))


def _eval_piece(piece: _Piece, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form position, velocity and acceleration at local times ``tau``."""
    n = tau.shape[0]
    pos = np.empty((n, 2))
    vel = np.empty((n, 2))
    acc = np.empty((n, 2))
    kind, p = piece.kind, piece.p
    if kind == "L":
        sx, sz, ux, uz, v0, a = p
        s = tau * (v0 + 0.5 * a * tau)
        ds = v0 + a * tau
        pos[:, 0], pos[:, 1] = sx + ux * s, sz + uz * s
        vel[:, 0], vel[:, 1] = ux * ds, uz * ds
        acc[:, 0], acc[:, 1] = ux * a, uz * a
    elif kind == "A":
        cx, cz, radius, w, th0, _ = p
        th = th0 + w * tau
        cs, sn = np.cos(th), np.sin(th)
        pos[:, 0], pos[:, 1] = cx + radius * cs, cz + radius * sn
        rw = radius * w
        vel[:, 0], vel[:, 1] = -rw * sn, rw * cs
        rww = rw * w
        acc[:, 0], acc[:, 1] = -rww * cs, -rww * sn
    elif kind == "H":
        cx, cz, ex, ez, amp, om, ph, dx, dz = p
        phi = om * tau + ph
        sn, cs = np.sin(phi), np.cos(phi)
        pos[:, 0], pos[:, 1] = cx + ex * amp * sn + dx * tau, cz + ez * amp * sn + dz * tau
        ao = amp * om
        vel[:, 0], vel[:, 1] = ex * ao * cs + dx, ez * ao * cs + dz
        aoo = ao * om
        acc[:, 0], acc[:, 1] = -ex * aoo * sn, -ez * aoo * sn
    else:
        sx, sz, h0, speed, k0, c = p
        s = speed * tau
        th = h0 + s * (k0 + 0.5 * c * s)
        integral = _clothoid_integral(h0, k0, c, s)
        pos[:, 0], pos[:, 1] = sx + integral.real, sz + integral.imag
        cs, sn = np.cos(th), np.sin(th)
        vel[:, 0], vel[:, 1] = speed * cs, speed * sn
        kv2 = (k0 + c * s) * speed * speed
        acc[:, 0], acc[:, 1] = -kv2 * sn, kv2 * cs
    return pos, vel, acc


def _natural_heading(piece: _Piece, tau: float) -> float:
    """Direction of travel implied by a token's parameters where its speed is zero."""
    p = piece.p
    if piece.kind == "L":
        return math.atan2(p[3], p[2])
    if piece.kind == "A":
        return p[4] + p[3] * tau + p[5] * math.pi / 2.0
    if piece.kind == "H":
        return math.atan2(p[3], p[2])
    s = p[3] * tau
    return p[2] + s * (p[4] + 0.5 * p[5] * s)


def _end_state(piece: _Piece) -> tuple[np.ndarray, float, float, float]:
    """Position, heading, speed and signed curvature at the piece's end."""
    pos, vel, acc = (x[0] for x in _eval_piece(piece, np.array([piece.duration])))
    speed = math.hypot(vel[0], vel[1])
    if speed > ZERO_SPEED:
        heading = math.atan2(vel[1], vel[0])
        kappa = (vel[0] * acc[1] - vel[1] * acc[0]) / speed**3
    else:
        # v(tau) ~ a (tau - T) just before a stop: the motion came from -a.
        amag = math.hypot(acc[0], acc[1])
        heading = math.atan2(-acc[1], -acc[0]) if amag > ZERO_SPEED else _natural_heading(piece, piece.duration)
        kappa = 0.0
    return pos, heading, speed, kappa


def _make_piece(token: Token, t0: float, prev: _Piece | None) -> _Piece:
    end = _end_state(prev) if prev is not None else None
    if isinstance(token, ClothoidToken):
        if end is None:
            p = (*token.start, token.heading, token.speed, token.curvature, token.curvature_slope)
        else:
            pos, heading, speed, kappa = end
            p = (float(pos[0]), float(pos[1]), heading, speed, kappa, token.curvature_slope)
        return _Piece("C", t0, token.duration, p)
    if isinstance(token, LineToken):
        sx, sz = token.start if end is None else (float(end[0][0]), float(end[0][1]))
        p = (sx, sz, math.cos(token.direction), math.sin(token.direction), token.speed, token.acceleration)
        return _Piece("L", t0, token.duration, p)
    if isinstance(token, ArcToken):
        w = token.turn * token.angular_velocity
        cx, cz = token.centre
        if end is not None:
            cx = float(end[0][0]) - token.radius * math.cos(token.start_angle)
            cz = float(end[0][1]) - token.radius * math.sin(token.start_angle)
        return _Piece("A", t0, token.duration, (cx, cz, token.radius, w, token.start_angle, float(token.turn)))
    if isinstance(token, HarmonicToken):
        ex, ez = math.cos(token.axis), math.sin(token.axis)
        cx, cz = token.centre
        if end is not None:
            lift = token.amplitude * math.sin(token.phase)
            cx, cz = float(end[0][0]) - ex * lift, float(end[0][1]) - ez * lift
        om = _TWO_PI * token.frequency
        p = (cx, cz, ex, ez, token.amplitude, om, token.phase, *token.drift)
        return _Piece("H", t0, token.duration, p)
    raise SpecError(f"not a motion token: {token!r}")


@lru_cache(maxsize=1024)
def _compile(track: Track) -> _Compiled:
    durations = [tok.duration for tok in track.tokens]
    pieces: list[_Piece] = []
    for i, token in enumerate(track.tokens):
        t0 = track.start + math.fsum(durations[:i])
        pieces.append(_make_piece(token, t0, pieces[-1] if pieces else None))
    origin = _eval_piece(pieces[0], np.zeros(1))[0][0]
    starts = np.array([p.t0 for p in pieces])
    return _Compiled(tuple(pieces), starts, track.start, track.end, origin)


def _eval_track(comp: _Compiled, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if len(comp.pieces) == 1:
        piece = comp.pieces[0]
        return _eval_piece(piece, t - piece.t0)
    idx = np.maximum(np.searchsorted(comp.starts, t, side="right") - 1, 0)
    n = t.shape[0]
    pos, vel, acc = np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2))
    for k in np.unique(idx):
        mask = idx == k
        piece = comp.pieces[k]
        pos[mask], vel[mask], acc[mask] = _eval_piece(piece, t[mask] - piece.t0)
    return pos, vel, acc


def _check_motion(motion) -> Motion:
    if not isinstance(motion, Motion):
        raise SpecError(f"not a Motion: {motion!r}")
    return motion


def _times(t) -> np.ndarray:
    try:
        arr = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError):
        raise SpecError(f"times must be real numbers, got {t!r}") from None
    if arr.ndim > 1:
        raise SpecError(f"times must be a 1-D array, got shape {arr.shape}")
    arr = arr.reshape(-1)
    if arr.size:
        if not np.isfinite(arr).all():
            raise SpecError(f"times must be finite, got {float(arr[~np.isfinite(arr)][0])!r}")
        low = float(arr.min())
        if low < 0.0:
            raise SpecError(f"times must be >= 0, got {low!r}")
    return arr


# ----------------------------------------------------------------------- evaluation


def evaluate(motion: Motion, t) -> MotionSample:
    """Exact r(t), v(t), a(t) of ``motion`` at times ``t`` (seconds, shape ``(n,)``)."""
    _check_motion(motion)
    t = _times(t)
    return _evaluate(motion, t)


def _evaluate(motion: Motion, t: np.ndarray) -> MotionSample:
    pos, vel, acc = _eval_track(_compile(motion.base), t)
    for overlay in motion.overlays:
        comp = _compile(overlay)
        p, v, a = _eval_track(comp, np.clip(t, comp.start, comp.end))
        pos += p - comp.origin
        inside = ((t >= comp.start) & (t <= comp.end))[:, None]
        vel += np.where(inside, v, 0.0)
        acc += np.where(inside, a, 0.0)
    return MotionSample(pos, vel, acc)


def curvature(motion: Motion, t, signed: bool = False) -> np.ndarray:
    """kappa = |v x a| / |v|^3 (paper eq. 1), ``(n,)``; 0 where the speed is <= :data:`ZERO_SPEED`.

    ``signed=True`` keeps the sign: positive when turning from +X toward +Z.
    """
    sample = evaluate(motion, t)
    v, a = sample.velocity, sample.acceleration
    cross = v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]
    speed = np.hypot(v[:, 0], v[:, 1])
    moving = speed > ZERO_SPEED
    kappa = np.zeros_like(speed)
    kappa[moving] = cross[moving] / speed[moving] ** 3
    return kappa if signed else np.abs(kappa)


# ------------------------------------------------------------------------- segments


@dataclass(frozen=True)
class _Segment:
    """A stretch of time on which one analytic description of the velocity holds.

    ``line``: velocity along the fixed direction ``u`` (``still`` if it is zero);
    ``arc``: constant ``speed`` with heading ``heading + rate (t - t0)``;
    ``general``: anything else (clothoids, drifting harmonics, active overlays).
    """

    t0: float
    t1: float
    kind: str
    piece: _Piece | None = None
    still: bool = False
    u: tuple[float, float] = (1.0, 0.0)
    heading: float = 0.0
    speed: float = 0.0
    rate: float = 0.0


def _classify(piece: _Piece, t0: float, t1: float) -> _Segment:
    p, tau = piece.p, t0 - piece.t0
    if piece.kind == "L":
        return _Segment(t0, t1, "line", piece, p[4] == 0.0 and p[5] == 0.0, (p[2], p[3]))
    if piece.kind == "H":
        if p[7] == 0.0 and p[8] == 0.0:
            return _Segment(t0, t1, "line", piece, p[4] == 0.0, (p[2], p[3]))
        return _Segment(t0, t1, "general", piece)
    if piece.kind == "A":
        cx, cz, radius, w, th0, turn = p
        if w == 0.0:
            h = th0 + turn * math.pi / 2.0
            return _Segment(t0, t1, "line", piece, True, (math.cos(h), math.sin(h)))
        heading = th0 + w * tau + math.copysign(math.pi / 2.0, w)
        return _Segment(t0, t1, "arc", piece, heading=heading, speed=radius * abs(w), rate=w)
    sx, sz, h0, speed, k0, c = p
    if speed == 0.0:
        return _Segment(t0, t1, "line", piece, True, (math.cos(h0), math.sin(h0)))
    if c != 0.0:
        return _Segment(t0, t1, "general", piece)
    heading = h0 + k0 * speed * tau
    if k0 == 0.0:
        return _Segment(t0, t1, "line", piece, False, (math.cos(heading), math.sin(heading)))
    return _Segment(t0, t1, "arc", piece, heading=heading, speed=speed, rate=speed * k0)


@lru_cache(maxsize=256)
def _segments(motion: Motion) -> tuple[_Segment, ...]:
    base = _compile(motion.base)
    overlays = [_compile(o) for o in motion.overlays]
    cuts = {p.t0 for p in base.pieces[1:]}
    for comp in overlays:
        cuts.update(p.t0 for p in comp.pieces)
        cuts.add(comp.end)
    edges = [0.0] + sorted(c for c in cuts if c > 0.0) + [math.inf]
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        if any(comp.start <= a < comp.end for comp in overlays):
            out.append(_Segment(a, b, "general"))
            continue
        k = max(int(np.searchsorted(base.starts, a, side="right")) - 1, 0)
        out.append(_classify(base.pieces[k], a, b))
    return tuple(out)


def _walk(motion: Motion, t: np.ndarray, handler, state, width: int) -> np.ndarray:
    """Run ``handler(segment, times, state) -> (values, end_state)`` over the segments in
    time order, carrying the state across joins; ``values`` has one row per time."""
    segs = _segments(motion)
    out = np.empty((t.shape[0], width))
    if not t.size:
        return out
    idx = np.searchsorted(np.array([s.t0 for s in segs]), t, side="right") - 1
    last = int(idx.max())
    for i in range(last + 1):
        mask = idx == i
        times = t[mask]
        n = times.shape[0]
        if i < last:
            times = np.append(times, segs[i + 1].t0)
        values, end = handler(segs[i], times, state)
        out[mask] = values[:n]
        state = end
    return out


def _grid(seg: _Segment, times: np.ndarray) -> tuple[np.ndarray, int]:
    """Index of the grid node at or before each time, and the number of full steps."""
    k = np.maximum(np.floor((times - seg.t0) / ROLL_STEP_S).astype(np.int64), 0)
    return k, int(k.max()) if k.size else 0


def _gauss(a: np.ndarray, h: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Times ``a + h * x`` for each quadrature node ``x``, shape ``(len(a), len(nodes))``."""
    return a[:, None] + h[:, None] * nodes[None, :]


def _weighted(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Row-wise weighted sums, accumulated term by term in a fixed order: unlike a BLAS
    product, a row's result does not depend on how many rows there are."""
    out = values[:, 0] * weights[0]
    for j in range(1, weights.shape[0]):
        out = out + values[:, j] * weights[j]
    return out


def _along(d: np.ndarray, u) -> np.ndarray:
    """Row-wise dot products of (n, 2) vectors with the direction ``u``."""
    return d[:, 0] * u[0] + d[:, 1] * u[1]


def _speed_at(motion: Motion, times: np.ndarray) -> np.ndarray:
    v = _evaluate(motion, times.reshape(-1)).velocity
    return np.hypot(v[:, 0], v[:, 1]).reshape(times.shape)


# ----------------------------------------------------------------------- arc length


def _piece_distance(piece: _Piece, tau: np.ndarray) -> np.ndarray:
    """Closed-form distance travelled since the piece's start (not for drifting H
    or curving clothoids, which are ``general`` segments)."""
    p = piece.p
    if piece.kind == "L":
        v0, a = p[4], p[5]
        signed = tau * (v0 + 0.5 * a * tau)
        if a >= 0.0:
            return signed
        stop = v0 / -a
        peak = stop * (v0 + 0.5 * a * stop)
        return np.where(tau <= stop, signed, 2.0 * peak - signed)
    if piece.kind == "H":
        amp, om, ph = p[4], p[5], p[6]

        def folded(phi: np.ndarray) -> np.ndarray:  # antiderivative of |cos|
            m = np.floor((phi + math.pi / 2.0) / math.pi)
            return 2.0 * m + np.where(m % 2 == 0, 1.0, -1.0) * np.sin(phi)

        return amp * (folded(om * tau + ph) - folded(np.array([ph]))[0])
    if piece.kind == "A":
        return p[2] * abs(p[3]) * tau
    return p[3] * tau


def arc_length(motion: Motion, t) -> np.ndarray:
    """Distance travelled on [0, t], ``(n,)``: closed form for L, A, undrifted H and
    constant-curvature C; fixed-grid 3-point Gauss-Legendre quadrature (6th order on
    :data:`ROLL_STEP_S` steps) for curving clothoids, drifting harmonics and overlays."""
    _check_motion(motion)
    t = _times(t)

    def handler(seg: _Segment, times: np.ndarray, start: float):
        if seg.kind != "general":
            piece = seg.piece
            d = _piece_distance(piece, times - piece.t0) - _piece_distance(piece, np.array([seg.t0 - piece.t0]))[0]
            vals = start + d
            return vals[:, None], float(vals[-1])
        k, steps = _grid(seg, times)
        a = seg.t0 + ROLL_STEP_S * np.arange(steps)
        full = _weighted(_speed_at(motion, _gauss(a, np.full(steps, ROLL_STEP_S), _GL3_X)), _GL3_W) * ROLL_STEP_S
        nodes = start + np.concatenate([[0.0], np.cumsum(full)])
        ak = seg.t0 + ROLL_STEP_S * k
        part = _weighted(_speed_at(motion, _gauss(ak, times - ak, _GL3_X)), _GL3_W) * (times - ak)
        vals = nodes[k] + part
        return vals[:, None], float(vals[-1])

    return _walk(motion, t, handler, 0.0, 1)[:, 0]


# ------------------------------------------------------------------------ rotations


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of ``(..., 4)`` quaternions stored ``(x, y, z, w)`` (pybullet order)."""
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def _qexp(rotvec: np.ndarray) -> np.ndarray:
    """Unit quaternion of the rotation vector (axis * angle), continuous through 0."""
    angle = np.linalg.norm(rotvec, axis=-1)
    half = 0.5 * np.sinc(angle / _TWO_PI)  # sin(angle / 2) / angle
    return np.concatenate([rotvec * half[..., None], np.cos(0.5 * angle)[..., None]], axis=-1)


def _qaxis(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotation by ``angle`` about the world axis 0 (X), 1 (Y) or 2 (Z)."""
    q = np.zeros(angle.shape + (4,))
    q[..., axis] = np.sin(0.5 * angle)
    q[..., 3] = np.cos(0.5 * angle)
    return q


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

    def handler(seg: _Segment, times: np.ndarray, q0: np.ndarray):
        if seg.kind == "line":
            pos = _evaluate(motion, np.append(times, seg.t0)).position
            dist = _along(pos[:-1] - pos[-1], seg.u)
            axis = np.array([seg.u[1], 0.0, -seg.u[0]])
            q = qmul(_qexp(np.outer(dist / radius, axis)), q0)
        elif seg.kind == "arc":
            tau = times - seg.t0
            w0 = seg.speed / radius * np.array([math.sin(seg.heading), 0.0, -math.cos(seg.heading)])
            w0[1] += seg.rate
            q = qmul(_qaxis(1, -seg.rate * tau), qmul(_qexp(np.outer(tau, w0)), q0))
        else:
            k, steps = _grid(seg, times)
            a = seg.t0 + ROLL_STEP_S * np.arange(steps)
            nodes = np.vstack([_IDENTITY, _scan(_magnus(motion, a, np.full(steps, ROLL_STEP_S), radius))])
            ak = seg.t0 + ROLL_STEP_S * k
            q = qmul(_magnus(motion, ak, times - ak, radius), qmul(nodes[k], q0))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        return q, q[-1]

    return _walk(motion, t, handler, _IDENTITY, 4)


def _magnus(motion: Motion, a: np.ndarray, h: np.ndarray, radius: float) -> np.ndarray:
    """One 4th-order Magnus step per row: the rotation over ``[a, a + h]`` as a quaternion."""
    g = _gauss(a, h, np.array(_MAGNUS_C))
    v = _evaluate(motion, g.reshape(-1)).velocity.reshape(g.shape + (2,))
    w = _roll_rate(v, radius)
    w1, w2 = w[:, 0], w[:, 1]
    hh = h[:, None]
    theta = 0.5 * hh * (w1 + w2) + (_SQRT3 / 12.0) * hh * hh * np.cross(w2, w1)
    return _qexp(theta)


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

    def handler(seg: _Segment, times: np.ndarray, state):
        prev, s0 = state
        if seg.kind == "line":
            direction = math.atan2(seg.u[1], seg.u[0])
            if prev is None:
                psi = float(_branch(direction, _FIRST_HEADING))
            elif seg.still:
                psi = prev
            else:
                psi = float(_branch(direction, prev))
            pos = _evaluate(motion, np.append(times, seg.t0)).position
            s = s0 + _along(pos[:-1] - pos[-1], (math.cos(psi), math.sin(psi)))
            out = np.column_stack([np.full(times.shape, psi), s])
        elif seg.kind == "arc":
            psi0 = float(_branch(seg.heading, _FIRST_HEADING if prev is None else prev))
            sign = 1.0 if round((psi0 - seg.heading) / math.pi) % 2 == 0 else -1.0
            tau = times - seg.t0
            out = np.column_stack([psi0 + seg.rate * tau, s0 + sign * seg.speed * tau])
        else:
            out = _cylinder_general(motion, seg, times, prev, s0)
        return out, (float(out[-1, 0]), float(out[-1, 1]))

    return _walk(motion, t, handler, (None, 0.0), 2)


def _cylinder_general(motion: Motion, seg: _Segment, times: np.ndarray, prev, s0: float) -> np.ndarray:
    k, steps = _grid(seg, times)
    nodes_t = seg.t0 + ROLL_STEP_S * np.arange(steps + 1)
    sample = _evaluate(motion, nodes_t)
    v, acc = sample.velocity, sample.acceleration
    moving = np.hypot(v[:, 0], v[:, 1]) > ZERO_SPEED
    raw = _heading_of(v)
    if not moving[0]:
        if prev is not None:
            raw[0] = prev
        elif math.hypot(*acc[0]) > ZERO_SPEED:
            raw[0] = math.atan2(acc[0, 1], acc[0, 0])
        elif seg.piece is not None:
            raw[0] = _natural_heading(seg.piece, seg.t0 - seg.piece.t0)
        else:
            raw[0] = 0.0
        moving[0] = True
    last_moving = np.maximum.accumulate(np.where(moving, np.arange(raw.size), 0))
    raw = raw[last_moving]
    psi_nodes = 0.5 * np.unwrap(2.0 * raw)
    psi_nodes += math.pi * round(((_FIRST_HEADING if prev is None else prev) - psi_nodes[0]) / math.pi)

    def signed_speed(at: np.ndarray, psi_ref: np.ndarray) -> np.ndarray:
        vel = _evaluate(motion, at.reshape(-1)).velocity.reshape(at.shape + (2,))
        along = vel[..., 0] * np.cos(psi_ref)[:, None] + vel[..., 1] * np.sin(psi_ref)[:, None]
        return np.copysign(np.hypot(vel[..., 0], vel[..., 1]), along)

    a = nodes_t[:-1]
    full = _weighted(signed_speed(_gauss(a, np.full(steps, ROLL_STEP_S), _GL3_X), psi_nodes[:-1]), _GL3_W) * ROLL_STEP_S
    s_nodes = s0 + np.concatenate([[0.0], np.cumsum(full)])
    ak = seg.t0 + ROLL_STEP_S * k
    h = times - ak
    s = s_nodes[k] + _weighted(signed_speed(_gauss(ak, h, _GL3_X), psi_nodes[k]), _GL3_W) * h
    vq = _evaluate(motion, times).velocity
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
        raise SpecError(f"object size must be a finite number > 0, got {size!r}")
    if category.rolling and not (category.shape == "sphere" or (category.shape == "cylinder" and category.lying)):
        raise SpecError(f"object {category.name!r}: only spheres and lying cylinders can roll")
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
    _check_motion(motion)
    t = _times(t)
    if not category.rolling:
        return np.tile(_IDENTITY, (t.shape[0], 1))
    radius = category.rolling_radius(size)
    if category.shape == "sphere":
        return _sphere_orientation(motion, radius, t)
    state = _cylinder_state(motion, radius, t)
    q = qmul(_qaxis(1, _FIRST_HEADING - state[:, 0]), _qaxis(0, state[:, 1] / radius))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def object_pose(motion: Motion, category: ObjectCategory | str, size: float, t) -> tuple[np.ndarray, np.ndarray]:
    """The target's poses ``(n, 7)`` = x, y, z, qx, qy, qz, qw and world velocities
    ``(n, 3)`` (vy = 0); y is the category's resting half height. See
    :func:`object_orientation` for the rotation conventions."""
    category = _category(category)
    size = _check_size(category, size)
    _check_motion(motion)
    t = _times(t)
    sample = _evaluate(motion, t)
    n = t.shape[0]
    pose = np.empty((n, 7))
    pose[:, 0] = sample.position[:, 0]
    pose[:, 1] = category.half_height(size)
    pose[:, 2] = sample.position[:, 1]
    pose[:, 3:] = object_orientation(motion, category, size, t)
    vel = np.zeros((n, 3))
    vel[:, 0], vel[:, 2] = sample.velocity[:, 0], sample.velocity[:, 1]
    return pose, vel


def object_angular_velocity(motion: Motion, category: ObjectCategory | str, size: float, t) -> np.ndarray:
    """World angular velocity ``(n, 3)`` matching :func:`object_orientation`, in closed form:
    0 for non-rolling objects; (+Y x v) / r for spheres; for lying cylinders that plus
    the yaw rate -dpsi/dt about +Y (dpsi/dt = (v x a) / |v|^2, 0 when standing still)."""
    category = _category(category)
    size = _check_size(category, size)
    _check_motion(motion)
    sample = evaluate(motion, t)
    n = sample.velocity.shape[0]
    if not category.rolling:
        return np.zeros((n, 3))
    v, a = sample.velocity, sample.acceleration
    w = _roll_rate(v, category.rolling_radius(size))
    if category.shape == "cylinder":
        speed2 = v[:, 0] ** 2 + v[:, 1] ** 2
        moving = speed2 > ZERO_SPEED**2
        rate = np.zeros(n)
        rate[moving] = (v[moving, 0] * a[moving, 1] - v[moving, 1] * a[moving, 0]) / speed2[moving]
        w[:, 1] = -rate
    return w


# --------------------------------------------------------------------------- bounds


def _cos_range(lo: float, hi: float) -> tuple[float, float]:
    """Exact min and max of cos over [lo, hi]."""
    if hi - lo >= _TWO_PI:
        return -1.0, 1.0
    values = [math.cos(lo), math.cos(hi)]
    k = math.ceil(lo / math.pi)
    while k * math.pi <= hi:
        values.append(1.0 if k % 2 == 0 else -1.0)
        k += 1
    return min(values), max(values)


def _scaled(centre: float, scale: float, lo: float, hi: float) -> tuple[float, float]:
    a, b = centre + scale * lo, centre + scale * hi
    return (a, b) if a <= b else (b, a)


def _harmonic_axis_bounds(c0: float, e: float, d: float, amp: float, om: float, ph: float, span: float):
    """Extremes of c0 + e amp sin(om tau + ph) + d tau over tau in [0, span]."""
    if d == 0.0:
        lo, hi = _cos_range(ph - math.pi / 2.0, ph + om * span - math.pi / 2.0)
        return _scaled(c0, e * amp, lo, hi)
    taus = [0.0, span]
    ea = e * amp * om
    if ea != 0.0 and abs(d / ea) < 1.0:
        root = math.acos(-d / ea)
        end = ph + om * span
        for base in (root, -root):
            m = math.ceil((ph - base) / _TWO_PI)
            while base + m * _TWO_PI <= end:
                taus.append((base + m * _TWO_PI - ph) / om)
                m += 1
    vals = [c0 + e * amp * math.sin(om * tau + ph) + d * tau for tau in taus]
    return min(vals), max(vals)


def _clothoid_candidates(h0: float, k0: float, c: float, length: float) -> list[float]:
    """Arc lengths in [0, length] where the heading is a multiple of pi/2 (x or z extreme)."""
    ends = [h0, h0 + length * (k0 + 0.5 * c * length)]
    if c != 0.0 and 0.0 < -k0 / c < length:
        ends.append(h0 - k0 * k0 / (2.0 * c))
    lo, hi = min(ends), max(ends)
    out = [0.0, length]
    m = math.ceil(lo / (math.pi / 2.0))
    while m * math.pi / 2.0 <= hi:
        target = m * math.pi / 2.0
        if c == 0.0:
            if k0 != 0.0:
                out.append((target - h0) / k0)
        else:
            disc = k0 * k0 - 2.0 * c * (h0 - target)
            if disc >= 0.0:
                r = math.sqrt(disc)
                q = -0.5 * (k0 + math.copysign(r, k0)) if k0 != 0.0 else -0.5 * r
                if q != 0.0:
                    out.append(2.0 * q / c)  # the two roots of (c/2) s^2 + k0 s + (h0 - target)
                    out.append((h0 - target) / q)
                else:
                    out.append(0.0)
        m += 1
    return [s for s in out if 0.0 <= s <= length]


def _piece_bounds(piece: _Piece, span: float) -> tuple[float, float, float, float]:
    p = piece.p
    if piece.kind == "L":
        sx, sz, ux, uz, v0, a = p
        dists = [0.0, span * (v0 + 0.5 * a * span)]
        if a < 0.0 and v0 / -a < span:
            stop = v0 / -a
            dists.append(stop * (v0 + 0.5 * a * stop))
        lo, hi = min(dists), max(dists)
        return (*_scaled(sx, ux, lo, hi), *_scaled(sz, uz, lo, hi))
    if piece.kind == "A":
        cx, cz, radius, w, th0, _ = p
        lo, hi = sorted((th0, th0 + w * span))
        return (*_scaled(cx, radius, *_cos_range(lo, hi)), *_scaled(cz, radius, *_cos_range(lo - math.pi / 2, hi - math.pi / 2)))
    if piece.kind == "H":
        cx, cz, ex, ez, amp, om, ph, dx, dz = p
        return (*_harmonic_axis_bounds(cx, ex, dx, amp, om, ph, span), *_harmonic_axis_bounds(cz, ez, dz, amp, om, ph, span))
    sx, sz, h0, speed, k0, c = p
    s = np.array(_clothoid_candidates(h0, k0, c, speed * span))
    z = _clothoid_integral(h0, k0, c, s)
    return sx + float(z.real.min()), sx + float(z.real.max()), sz + float(z.imag.min()), sz + float(z.imag.max())


def _sampled_bounds(motion: Motion, ts: np.ndarray) -> tuple[float, float, float, float]:
    pos = _evaluate(motion, ts).position
    axis = np.array([0, 0, 1, 1])
    sign = np.array([-1.0, 1.0, -1.0, 1.0])  # maximise sign * coordinate
    values = sign[None, :] * pos[:, axis]
    best = values.argmax(axis=0)
    lo = ts[np.maximum(best - 1, 0)]
    hi = ts[np.minimum(best + 1, ts.size - 1)]
    top = values[best, np.arange(4)]
    for _ in range(16):
        mid = 0.5 * (lo + hi)
        sample = _evaluate(motion, mid)
        rising = sign * sample.velocity[np.arange(4), axis] > 0.0
        top = np.maximum(top, sign * sample.position[np.arange(4), axis])
        lo, hi = np.where(rising, mid, lo), np.where(rising, hi, mid)
    out = sign * top
    return float(out[0]), float(out[1]), float(out[2]), float(out[3])


def motion_bounds(motion: Motion, t_end: float, samples: int = 512) -> tuple[float, float, float, float]:
    """``(x_min, x_max, z_min, z_max)`` of the position over ``[0, t_end]``.

    Exact (closed-form extremes) for motions without overlays. With overlays the sum of
    tracks has no cheap closed form: the extremes over ``samples`` evenly spaced times
    plus every token boundary, each refined by bisection on the sign of that velocity
    component between the best sample's neighbours (exact to ~1e-10 for a smooth
    extreme; it could only miss one that is not the best sample's, i.e. within
    max|a| (t_end / samples)^2 / 8 of it).
    """
    if isinstance(t_end, bool) or not isinstance(t_end, (int, float, np.floating)) or not math.isfinite(t_end) or t_end < 0:
        raise SpecError(f"t_end must be a finite number >= 0, got {t_end!r}")
    t_end = float(t_end)
    _check_motion(motion)
    if motion.overlays:
        if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 2:
            raise SpecError(f"samples must be >= 2, got {samples!r}")
        cuts = [s.t0 for s in _segments(motion) if s.t0 <= t_end]
        return _sampled_bounds(motion, np.unique(np.concatenate([np.linspace(0.0, t_end, samples), cuts])))
    tokens = motion.base.tokens
    if len(tokens) == 1:
        return _piece_bounds(_make_piece(tokens[0], 0.0, None), t_end)
    pieces = _compile(motion.base).pieces
    x0 = z0 = math.inf
    x1 = z1 = -math.inf
    for i, piece in enumerate(pieces):
        if piece.t0 > t_end:
            break
        span = t_end - piece.t0 if i == len(pieces) - 1 else min(piece.duration, t_end - piece.t0)
        a, b, c, d = _piece_bounds(piece, span)
        x0, x1, z0, z1 = min(x0, a), max(x1, b), min(z0, c), max(z1, d)
    return x0, x1, z0, z1
