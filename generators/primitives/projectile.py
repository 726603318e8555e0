"""``P``: drag-free ballistic flight with bounces, the only token that leaves the table.

In the table plane a flight is a line at the constant horizontal velocity (the line
piece's closed forms, :class:`generators.primitives.line.StraightLine`); vertically it
is a sequence of closed-form arcs (:func:`flight`, summed up by :mod:`generators.ballistics`).
"""

from __future__ import annotations

import math

from generators.primitives.base import EndState, FlightArc, Piece, register
from generators.primitives.line import StraightLine
from schemas.motion import ProjectileToken

#: A bounce slower than this (units/s, 5 mm/s) ends the bouncing: the object rests.
REST_SPEED = 0.05
#: Bounces computed before the object is put to rest regardless of speed.
MAX_BOUNCES = 64


def _landing(y0: float, v0: float, g: float) -> float:
    """Time after launch at which ``y0 + v0 t - g t^2 / 2`` returns to 0 (the later root)."""
    return (v0 + math.sqrt(v0 * v0 + 2.0 * g * y0)) / g


def flight(token: ProjectileToken, t0: float, t1: float, y0: float) -> tuple[list[FlightArc], float]:
    """The arcs of ``token`` on ``[t0, t1)`` launched from elevation ``y0``, and the
    elevation at ``t1`` (``t1`` may be infinite: the last token flies until it rests)."""
    g, v0, t = token.gravity, token.velocity[1], t0
    arcs: list[FlightArc] = []
    for bounce in range(MAX_BOUNCES + 1):
        if (y0 <= 0.0 and v0 < REST_SPEED) or bounce == MAX_BOUNCES:
            arcs.append(FlightArc(t, 0.0, 0.0, 0.0))
            return arcs, 0.0
        arcs.append(FlightArc(t, y0, v0, g))
        land = t + _landing(y0, v0, g)
        if land >= t1:
            tau = t1 - t
            return arcs, max(y0 + tau * (v0 - 0.5 * g * tau), 0.0)
        impact = v0 - g * (land - t)
        t, y0, v0 = land, 0.0, -token.restitution * impact
    raise AssertionError("unreachable")


@register(ProjectileToken)
class Projectile(StraightLine[ProjectileToken]):
    """``P`` tokens: a constant-velocity line in the plan view, flights and bounces above it."""

    def place(self, token: ProjectileToken, t0: float, prev: EndState | None) -> Piece:
        sx, sz = token.start if prev is None else (float(prev.position[0]), float(prev.position[1]))
        vx, vz = token.velocity[0], token.velocity[2]
        speed = math.hypot(vx, vz)
        ux, uz = (vx / speed, vz / speed) if speed > 0.0 else (1.0, 0.0)
        return Piece(self, t0, token.duration, (sx, sz, ux, uz, speed, 0.0))

    def lift(self, token: ProjectileToken, index: int, t0: float, t1: float, y: float) -> tuple[list[FlightArc], float]:
        """Launched from ``token.height`` when it opens the track, else from where the object is."""
        return flight(token, t0, t1, token.height if index == 0 else y)
