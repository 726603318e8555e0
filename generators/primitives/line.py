"""``L``: a straight line, r(t) = start + u (speed t + acceleration t^2 / 2).

Piece parameters ``p = (sx, sz, ux, uz, v0, acc)``: the start, the unit direction, the
initial speed and the acceleration along it.
"""

from __future__ import annotations

import math

import numpy as np

from generators.primitives.base import XZ, Box, EndState, Piece, Primitive, Segment, TokenT, register
from generators.primitives.extremes import scaled_range
from schemas.motion import LineToken


class StraightLine(Primitive[TokenT]):
    """The closed forms of a line piece, shared by ``L`` and ``P`` (whose plan view is a line)."""

    def evaluate(self, piece: Piece, tau: np.ndarray) -> XZ:
        n = tau.shape[0]
        pos, vel, acc = np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2))
        sx, sz, ux, uz, v0, a = piece.p
        s = tau * (v0 + 0.5 * a * tau)
        ds = v0 + a * tau
        pos[:, 0], pos[:, 1] = sx + ux * s, sz + uz * s
        vel[:, 0], vel[:, 1] = ux * ds, uz * ds
        acc[:, 0], acc[:, 1] = ux * a, uz * a
        return pos, vel, acc

    def natural_heading(self, piece: Piece, tau: float) -> float:
        return math.atan2(piece.p[3], piece.p[2])

    def segment(self, piece: Piece, t0: float, t1: float) -> Segment:
        p = piece.p
        return Segment(t0, t1, "line", piece, p[4] == 0.0 and p[5] == 0.0, (p[2], p[3]))

    def distance(self, piece: Piece, tau: np.ndarray) -> np.ndarray:
        v0, a = piece.p[4], piece.p[5]
        signed = tau * (v0 + 0.5 * a * tau)
        if a >= 0.0:
            return signed
        stop = v0 / -a
        peak = stop * (v0 + 0.5 * a * stop)
        return np.where(tau <= stop, signed, 2.0 * peak - signed)

    def bounds(self, piece: Piece, span: float) -> Box:
        sx, sz, ux, uz, v0, a = piece.p
        dists = [0.0, span * (v0 + 0.5 * a * span)]
        if a < 0.0 and v0 / -a < span:
            stop = v0 / -a
            dists.append(stop * (v0 + 0.5 * a * stop))
        lo, hi = min(dists), max(dists)
        return (*scaled_range(sx, ux, lo, hi), *scaled_range(sz, uz, lo, hi))


@register(LineToken)
class Line(StraightLine[LineToken]):
    """``L`` tokens: a line from ``start`` (or the previous token's end) along ``direction``."""

    def place(self, token: LineToken, t0: float, prev: EndState | None) -> Piece:
        sx, sz = token.start if prev is None else (float(prev.position[0]), float(prev.position[1]))
        p = (sx, sz, math.cos(token.direction), math.sin(token.direction), token.speed, token.acceleration)
        return Piece(self, t0, token.duration, p)
