"""``A``: a circular arc, r(t) = centre + radius (cos th, sin th), th = start_angle + w t.

Piece parameters ``p = (cx, cz, R, w, th0, turn)`` with the signed angular velocity ``w``.
"""

from __future__ import annotations

import math

import numpy as np

from generators.primitives.base import XZ, Box, EndState, Piece, Primitive, Segment, register
from generators.primitives.extremes import cos_range, scaled_range
from schemas.motion import ArcToken


@register(ArcToken)
class Arc(Primitive[ArcToken]):
    """``A`` tokens; after another token the centre moves so the arc starts at its end."""

    def place(self, token: ArcToken, t0: float, prev: EndState | None) -> Piece:
        w = token.turn * token.angular_velocity
        cx, cz = token.centre
        if prev is not None:
            cx = float(prev.position[0]) - token.radius * math.cos(token.start_angle)
            cz = float(prev.position[1]) - token.radius * math.sin(token.start_angle)
        return Piece(self, t0, token.duration, (cx, cz, token.radius, w, token.start_angle, float(token.turn)))

    def evaluate(self, piece: Piece, tau: np.ndarray) -> XZ:
        n = tau.shape[0]
        pos, vel, acc = np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2))
        cx, cz, radius, w, th0, _ = piece.p
        th = th0 + w * tau
        cs, sn = np.cos(th), np.sin(th)
        pos[:, 0], pos[:, 1] = cx + radius * cs, cz + radius * sn
        rw = radius * w
        vel[:, 0], vel[:, 1] = -rw * sn, rw * cs
        rww = rw * w
        acc[:, 0], acc[:, 1] = -rww * cs, -rww * sn
        return pos, vel, acc

    def natural_heading(self, piece: Piece, tau: float) -> float:
        p = piece.p
        return p[4] + p[3] * tau + p[5] * math.pi / 2.0

    def segment(self, piece: Piece, t0: float, t1: float) -> Segment:
        cx, cz, radius, w, th0, turn = piece.p
        if w == 0.0:
            h = th0 + turn * math.pi / 2.0
            return Segment(t0, t1, "line", piece, True, (math.cos(h), math.sin(h)))
        heading = th0 + w * (t0 - piece.t0) + math.copysign(math.pi / 2.0, w)
        return Segment(t0, t1, "arc", piece, heading=heading, speed=radius * abs(w), rate=w)

    def distance(self, piece: Piece, tau: np.ndarray) -> np.ndarray:
        return piece.p[2] * abs(piece.p[3]) * tau

    def bounds(self, piece: Piece, span: float) -> Box:
        cx, cz, radius, w, th0, _ = piece.p
        lo, hi = sorted((th0, th0 + w * span))
        return (*scaled_range(cx, radius, *cos_range(lo, hi)),
                *scaled_range(cz, radius, *cos_range(lo - math.pi / 2, hi - math.pi / 2)))
