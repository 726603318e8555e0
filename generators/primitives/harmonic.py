"""``H``: simple harmonic motion along an axis with optional drift,
r(t) = centre + e amp sin(om t + phase) + drift t.

Piece parameters ``p = (cx, cz, ex, ez, amp, om, phase, dx, dz)``: the centre, the unit
axis ``e``, the amplitude, the angular frequency, the phase and the drift velocity.
"""

from __future__ import annotations

import math

import numpy as np

from generators.primitives.base import XZ, Box, EndState, Piece, Primitive, Segment, register
from generators.primitives.extremes import TWO_PI, cos_range, scaled_range
from schemas.motion import HarmonicToken


def _folded(phi: np.ndarray) -> np.ndarray:
    """An antiderivative of |cos|."""
    m = np.floor((phi + math.pi / 2.0) / math.pi)
    return 2.0 * m + np.where(m % 2 == 0, 1.0, -1.0) * np.sin(phi)


def _axis_bounds(c0: float, e: float, d: float, amp: float, om: float, ph: float, span: float) -> tuple[float, float]:
    """Extremes of c0 + e amp sin(om tau + ph) + d tau over tau in [0, span]."""
    if d == 0.0:
        lo, hi = cos_range(ph - math.pi / 2.0, ph + om * span - math.pi / 2.0)
        return scaled_range(c0, e * amp, lo, hi)
    taus = [0.0, span]
    ea = e * amp * om
    if ea != 0.0 and abs(d / ea) < 1.0:
        root = math.acos(-d / ea)
        end = ph + om * span
        for base in (root, -root):
            m = math.ceil((ph - base) / TWO_PI)
            while base + m * TWO_PI <= end:
                taus.append((base + m * TWO_PI - ph) / om)
                m += 1
    vals = [c0 + e * amp * math.sin(om * tau + ph) + d * tau for tau in taus]
    return min(vals), max(vals)


@register(HarmonicToken)
class Harmonic(Primitive[HarmonicToken]):
    """``H`` tokens; after another token the centre moves so the swing starts at its end."""

    def place(self, token: HarmonicToken, t0: float, prev: EndState | None) -> Piece:
        ex, ez = math.cos(token.axis), math.sin(token.axis)
        cx, cz = token.centre
        if prev is not None:
            lift = token.amplitude * math.sin(token.phase)
            cx, cz = float(prev.position[0]) - ex * lift, float(prev.position[1]) - ez * lift
        om = TWO_PI * token.frequency
        p = (cx, cz, ex, ez, token.amplitude, om, token.phase, *token.drift)
        return Piece(self, t0, token.duration, p)

    def evaluate(self, piece: Piece, tau: np.ndarray) -> XZ:
        n = tau.shape[0]
        pos, vel, acc = np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2))
        cx, cz, ex, ez, amp, om, ph, dx, dz = piece.p
        phi = om * tau + ph
        sn, cs = np.sin(phi), np.cos(phi)
        pos[:, 0], pos[:, 1] = cx + ex * amp * sn + dx * tau, cz + ez * amp * sn + dz * tau
        ao = amp * om
        vel[:, 0], vel[:, 1] = ex * ao * cs + dx, ez * ao * cs + dz
        aoo = ao * om
        acc[:, 0], acc[:, 1] = -ex * aoo * sn, -ez * aoo * sn
        return pos, vel, acc

    def natural_heading(self, piece: Piece, tau: float) -> float:
        return math.atan2(piece.p[3], piece.p[2])

    def segment(self, piece: Piece, t0: float, t1: float) -> Segment:
        p = piece.p
        if p[7] == 0.0 and p[8] == 0.0:
            return Segment(t0, t1, "line", piece, p[4] == 0.0, (p[2], p[3]))
        return Segment(t0, t1, "general", piece)

    def distance(self, piece: Piece, tau: np.ndarray) -> np.ndarray:
        amp, om, ph = piece.p[4], piece.p[5], piece.p[6]
        return amp * (_folded(om * tau + ph) - _folded(np.array([ph]))[0])

    def bounds(self, piece: Piece, span: float) -> Box:
        cx, cz, ex, ez, amp, om, ph, dx, dz = piece.p
        return (*_axis_bounds(cx, ex, dx, amp, om, ph, span), *_axis_bounds(cz, ez, dz, amp, om, ph, span))
