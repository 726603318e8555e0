"""Disturbances: a seeded change of the object's motion after the observe window, so a
policy's anticipation must be revised mid-approach (the paper's "recover from
disturbances").

At a time drawn in the approach (between :data:`EARLIEST` frames after the first acting
frame and :data:`LATEST` frames before the interception frame) the motion is cut and
continued by a line token (``L``, composed from the existing vocabulary, position and so
path continuous) whose velocity is the object's velocity at that time either scaled
(``speed``: x 0.5-0.75 or x 1.33-1.6) or turned (``heading``: 25-60 degrees left or
right). The draws come from ``SeedSequence([DISTURB_SEED, spec hash])``: the same episode
is always disturbed the same way. A disturbance that would take the object out of the
workspace or the view, or make the episode impossible to intercept, is redrawn (up to
:data:`ATTEMPTS` times; then the episode runs undisturbed). Motions with overlays or a
flight (``P``) are not disturbed.

The disturbed spec is what the run records (its ``spec`` column), with its ``disturbance``
(frame, kind, amount), so replays and scoring see exactly the motion the policy faced and
when it changed (the start of its last base token, :func:`disturbance_time`).
"""

from __future__ import annotations

import dataclasses
import math
from fractions import Fraction

import numpy as np

from generators.ground_truth import plan
from generators.tracks import evaluate
from schemas.errors import InfeasibleError
from schemas.motion import LineToken, Motion, Track
from schemas.spec import Disturbance, EpisodeSpec, implied_motion_types
from schemas.versions import FPS

DISTURB_SEED = 52_000
#: Frames after the first acting frame, and before the interception frame, that a
#: disturbance keeps clear of.
EARLIEST = 3
LATEST = 3
ATTEMPTS = 16
SPEED_FACTORS = ((0.5, 0.75), (1.33, 1.6))
TURN_DEGREES = (25.0, 60.0)


def _cut(motion: Motion, at: float) -> tuple:
    """The base tokens up to ``at`` seconds (the active one shortened)."""
    kept = []
    start = Fraction(0)
    for token in motion.base.tokens:
        end = start + Fraction(token.duration)
        if end <= Fraction(at):
            kept.append(token)
        else:
            if Fraction(at) > start:
                kept.append(dataclasses.replace(token, duration=float(Fraction(at) - start)))
            break
        start = end
    return tuple(kept)


def disturbed_spec(spec: EpisodeSpec) -> tuple[EpisodeSpec, Disturbance | None]:
    """``spec`` with its seeded disturbance (recorded in its ``disturbance`` field), and
    that disturbance (None: left undisturbed)."""
    if spec.motion.overlays or spec.motion.airborne or spec.intercept_frame - spec.observe_frames <= EARLIEST + LATEST:
        return spec, None
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([DISTURB_SEED, int(spec.spec_hash[:16], 16)])))
    first, last = spec.observe_frames + EARLIEST, spec.intercept_frame - LATEST
    for _ in range(ATTEMPTS):
        frame = first + int(rng.random() * (last - first + 1))
        at = frame / FPS
        velocity = evaluate(spec.motion, [at]).velocity[0]
        speed, heading = float(np.hypot(*velocity)), math.atan2(velocity[1], velocity[0])
        if rng.random() < 0.5:
            low, high = SPEED_FACTORS[int(rng.random() * 2)]
            factor = low + (high - low) * float(rng.random())
            what = Disturbance(frame, "speed", round(factor, 4))
            speed *= factor
        else:
            turn = math.radians(TURN_DEGREES[0] + (TURN_DEGREES[1] - TURN_DEGREES[0]) * float(rng.random()))
            turn *= 1.0 if rng.random() < 0.5 else -1.0
            what = Disturbance(frame, "heading", round(math.degrees(turn), 2))
            heading += turn
        if speed <= 1e-6:
            continue
        rest = spec.motion.duration - at
        line = LineToken(start=(0.0, 0.0), direction=heading, speed=speed, acceleration=0.0, duration=max(rest, 1.0 / FPS))
        motion = Motion(Track(_cut(spec.motion, at) + (line,)))
        motion_type = spec.motion_type if spec.motion_type in implied_motion_types(motion) else "custom"
        candidate = dataclasses.replace(spec, motion=motion, motion_type=motion_type, disturbance=what)
        try:
            plan(candidate)
        except InfeasibleError:
            continue
        return candidate, what
    return spec, None


def disturbance_time(spec: EpisodeSpec) -> float:
    """When a disturbed spec's motion changed: the start of its last base token (s)."""
    return math.fsum(t.duration for t in spec.motion.base.tokens[:-1])
