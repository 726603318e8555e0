"""Motion tracks compiled into closed-form pieces: r(t), v(t), a(t) and curvature of a
motion at any times (the semantics are in :mod:`generators.motion`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache

import numpy as np
from scipy.special import fresnel

from schemas.errors import SpecError
from schemas.motion import (
    ArcToken,
    ClothoidToken,
    HarmonicToken,
    LineToken,
    Motion,
    ProjectileToken,
    Token,
    Track,
)

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


def _weighted(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Row-wise weighted sums, accumulated term by term in a fixed order: unlike a BLAS
    product, a row's result does not depend on how many rows there are."""
    out = values[:, 0] * weights[0]
    for j in range(1, weights.shape[0]):
        out = out + values[:, j] * weights[j]
    return out


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
    if isinstance(token, ProjectileToken):
        # In the table plane a flight is a line at constant velocity (generators.ballistics
        # adds the height).
        sx, sz = token.start if end is None else (float(end[0][0]), float(end[0][1]))
        vx, vz = token.velocity[0], token.velocity[2]
        speed = math.hypot(vx, vz)
        ux, uz = (vx / speed, vz / speed) if speed > 0.0 else (1.0, 0.0)
        return _Piece("L", t0, token.duration, (sx, sz, ux, uz, speed, 0.0))
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
    pieces: list[_Piece] = []
    elapsed = Fraction(0)  # exact, so each start is the correctly rounded prefix sum (as math.fsum gives) in linear time
    for token in track.tokens:
        t0 = track.start + float(elapsed)
        pieces.append(_make_piece(token, t0, pieces[-1] if pieces else None))
        elapsed += Fraction(token.duration)
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
