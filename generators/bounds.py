"""Cheap, safe XZ bounds of a motion's path (closed form per piece, sampled for overlays)."""

from __future__ import annotations

import math

import numpy as np

from generators.segments import _segments
from generators.tracks import (
    _TWO_PI,
    _check_motion,
    _clothoid_integral,
    _compile,
    _evaluate,
    _make_piece,
    _Piece,
)
from schemas.errors import SpecError
from schemas.motion import (
    Motion,
)

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
