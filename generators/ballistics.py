"""Height of the target above its resting height: drag-free flight and bounces of ``P``.

Every token but ``P`` keeps the object on the table (elevation 0). A ``P`` token's
vertical motion is a sequence of closed-form arcs, each ``y(tau) = y0 + v0 tau - g tau^2 / 2``
(so ``vy = v0 - g tau``, ``ay = -g``), from its launch until it lands (y = 0), then one arc
per bounce with upward speed ``restitution x`` the impact speed, until a bounce would be
slower than :data:`REST_SPEED` (or after :data:`MAX_BOUNCES`): from then on it rests on the
table (y = vy = ay = 0) and slides on at its horizontal velocity.

Horizontally a ``P`` is a line at constant velocity (:mod:`generators.primitives.projectile`,
which also computes the arcs), so the object's orientation is that of the same planar motion (:mod:`generators.rolling`):
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
import numpy.typing as npt

from generators.primitives import FlightArc, primitive_for
from generators.primitives.projectile import MAX_BOUNCES, REST_SPEED
from generators.tracks import as_times, check_motion, compile_track
from schemas.motion import Motion

__all__ = ["MAX_BOUNCES", "REST_SPEED", "Elevation", "elevation"]


@dataclass(frozen=True)
class Elevation:
    """Height above the resting height, its rate and acceleration, each ``(n,)`` float64."""

    height: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


@lru_cache(maxsize=256)
def _schedule(motion: Motion) -> tuple[FlightArc, ...]:
    """The base track's elevation arcs in time order, each token's from its primitive."""
    pieces = compile_track(motion.base).pieces
    arcs: list[FlightArc] = []
    y = 0.0
    for k, (token, piece) in enumerate(zip(motion.base.tokens, pieces)):
        t1 = pieces[k + 1].t0 if k + 1 < len(pieces) else math.inf
        lifted, y = primitive_for(token).lift(token, k, piece.t0, t1, y)
        arcs.extend(lifted)
    return tuple(arcs)


def elevation(motion: Motion, t: npt.ArrayLike) -> Elevation:
    """The object's height above its resting height at times ``t`` (seconds), exact."""
    check_motion(motion)
    times = as_times(t)
    n = times.shape[0]
    height, velocity, acceleration = np.zeros(n), np.zeros(n), np.zeros(n)
    if not motion.airborne:
        return Elevation(height, velocity, acceleration)
    arcs = _schedule(motion)
    starts = np.array([a.t0 for a in arcs])
    idx = np.maximum(np.searchsorted(starts, times, side="right") - 1, 0)
    for k in np.unique(idx):
        arc = arcs[int(k)]
        if arc.g == 0.0:
            continue
        mask = idx == k
        tau = times[mask] - arc.t0
        height[mask] = np.maximum(arc.y0 + tau * (arc.v0 - 0.5 * arc.g * tau), 0.0)
        velocity[mask] = arc.v0 - arc.g * tau
        acceleration[mask] = -arc.g
    return Elevation(height, velocity, acceleration)

