"""Height of the target above its resting height: drag-free flight and bounces of ``P``.

Every token but ``P`` keeps the object on the table (elevation 0). A ``P`` token's
vertical motion is a sequence of closed-form arcs, each ``y(tau) = y0 + v0 tau - g tau^2 / 2``
(so ``vy = v0 - g tau``, ``ay = -g``), from its launch until it lands (y = 0), then one arc
per bounce with upward speed ``restitution x`` the impact speed, until a bounce would be
slower than :data:`REST_SPEED` (or after :data:`MAX_BOUNCES`): from then on it rests on the
table (y = vy = ay = 0) and slides on at its horizontal velocity.

Horizontally a ``P`` is a line at constant velocity (:mod:`generators.tracks`), so the
object's orientation is that of the same planar motion (:mod:`generators.rolling`):
a rolling object (sphere, lying cylinder) spins in flight at its rolling rate about the
horizontal axis across its travel (topspin equal to the rolling rate: angular momentum is
conserved in free flight, and it lands already rolling without slip); any other object
flies without turning. Landing and bounces change only the vertical velocity.

A planar token after a ``P`` needs the object back on the table: a motion whose ``P`` is
still in the air where the next token begins raises :class:`SpecError`. Times past the
base track's end extrapolate the last token, like the planar closed forms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from generators.tracks import _check_motion, _compile, _times
from schemas.errors import SpecError
from schemas.motion import Motion, ProjectileToken

#: A bounce slower than this (units/s, 5 mm/s) ends the bouncing: the object rests.
REST_SPEED = 0.05
#: Bounces computed before the object is put to rest regardless of speed.
MAX_BOUNCES = 64
#: How far from the table (units) a planar token may find the object at its start.
ON_TABLE = 1e-9


@dataclass(frozen=True)
class Elevation:
    """Height above the resting height, its rate and acceleration, each ``(n,)`` float64."""

    height: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


@dataclass(frozen=True)
class _Arc:
    t0: float
    y0: float
    v0: float
    g: float  # 0 for a rest


def _landing(y0: float, v0: float, g: float) -> float:
    """Time after launch at which ``y0 + v0 t - g t^2 / 2`` returns to 0 (the later root)."""
    return (v0 + math.sqrt(v0 * v0 + 2.0 * g * y0)) / g


def _flight(token: ProjectileToken, t0: float, t1: float, y0: float) -> tuple[list[_Arc], float]:
    """The arcs of ``token`` on ``[t0, t1)`` launched from elevation ``y0``, and the
    elevation at ``t1`` (``t1`` may be infinite: the last token flies until it rests)."""
    g, v0, t = token.gravity, token.velocity[1], t0
    arcs: list[_Arc] = []
    for bounce in range(MAX_BOUNCES + 1):
        if (y0 <= 0.0 and v0 < REST_SPEED) or bounce == MAX_BOUNCES:
            arcs.append(_Arc(t, 0.0, 0.0, 0.0))
            return arcs, 0.0
        arcs.append(_Arc(t, y0, v0, g))
        land = t + _landing(y0, v0, g)
        if land >= t1:
            tau = t1 - t
            return arcs, max(y0 + tau * (v0 - 0.5 * g * tau), 0.0)
        impact = v0 - g * (land - t)
        t, y0, v0 = land, 0.0, -token.restitution * impact
    raise AssertionError("unreachable")


@lru_cache(maxsize=256)
def _schedule(motion: Motion) -> tuple[_Arc, ...]:
    pieces = _compile(motion.base).pieces
    tokens = motion.base.tokens
    arcs: list[_Arc] = []
    y = 0.0
    for k, (token, piece) in enumerate(zip(tokens, pieces)):
        t1 = pieces[k + 1].t0 if k + 1 < len(pieces) else math.inf
        if isinstance(token, ProjectileToken):
            launch = token.height if k == 0 else y
            flight, y = _flight(token, piece.t0, t1, launch)
            arcs.extend(flight)
            continue
        if y > ON_TABLE:
            raise SpecError(
                f"token {k} ({token.type}) starts at {piece.t0:.3f} s with the object still {y:.3f} units in the "
                f"air: a planar token after a projectile needs it back on the table"
            )
        arcs.append(_Arc(piece.t0, 0.0, 0.0, 0.0))
    return tuple(arcs)


def elevation(motion: Motion, t) -> Elevation:
    """The object's height above its resting height at times ``t`` (seconds), exact."""
    _check_motion(motion)
    t = _times(t)
    n = t.shape[0]
    height, velocity, acceleration = np.zeros(n), np.zeros(n), np.zeros(n)
    if not motion.airborne:
        return Elevation(height, velocity, acceleration)
    arcs = _schedule(motion)
    starts = np.array([a.t0 for a in arcs])
    idx = np.maximum(np.searchsorted(starts, t, side="right") - 1, 0)
    for k in np.unique(idx):
        arc = arcs[int(k)]
        if arc.g == 0.0:
            continue
        mask = idx == k
        tau = t[mask] - arc.t0
        height[mask] = np.maximum(arc.y0 + tau * (arc.v0 - 0.5 * arc.g * tau), 0.0)
        velocity[mask] = arc.v0 - arc.g * tau
        acceleration[mask] = -arc.g
    return Elevation(height, velocity, acceleration)

