"""Cheap, safe XZ bounds of a motion's path (closed form per piece from its primitive,
sampled for overlays)."""

from __future__ import annotations

import math

import numpy as np

from generators.segments import segments
from generators.tracks import check_motion, compile_track, place, sample_motion
from schemas.errors import SpecError
from schemas.motion import Motion
from schemas.names import shorten


def _sampled_bounds(motion: Motion, ts: np.ndarray) -> tuple[float, float, float, float]:
    pos = sample_motion(motion, ts).position
    axis = np.array([0, 0, 1, 1])
    sign = np.array([-1.0, 1.0, -1.0, 1.0])  # maximise sign * coordinate
    values = sign[None, :] * pos[:, axis]
    best = values.argmax(axis=0)
    lo = ts[np.maximum(best - 1, 0)]
    hi = ts[np.minimum(best + 1, ts.size - 1)]
    top = values[best, np.arange(4)]
    for _ in range(16):
        mid = 0.5 * (lo + hi)
        at = sample_motion(motion, mid)
        rising = sign * at.velocity[np.arange(4), axis] > 0.0
        top = np.maximum(top, sign * at.position[np.arange(4), axis])
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
        raise SpecError(f"t_end must be a finite number >= 0, got {shorten(repr(t_end))}")
    t_end = float(t_end)
    check_motion(motion)
    if motion.overlays:
        if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 2:
            raise SpecError(f"samples must be >= 2, got {shorten(repr(samples))}")
        cuts = [s.t0 for s in segments(motion) if s.t0 <= t_end]
        return _sampled_bounds(motion, np.unique(np.concatenate([np.linspace(0.0, t_end, samples), cuts])))
    tokens = motion.base.tokens
    if len(tokens) == 1:
        piece = place(tokens[0], 0.0, None)
        return piece.primitive.bounds(piece, t_end)
    pieces = compile_track(motion.base).pieces
    x0 = z0 = math.inf
    x1 = z1 = -math.inf
    for i, piece in enumerate(pieces):
        if piece.t0 > t_end:
            break
        span = t_end - piece.t0 if i == len(pieces) - 1 else min(piece.duration, t_end - piece.t0)
        a, b, c, d = piece.primitive.bounds(piece, span)
        x0, x1, z0, z1 = min(x0, a), max(x1, b), min(z0, c), max(z1, d)
    return x0, x1, z0, z1
