"""Irregular-to-regular motions (paper A.11): a seeded smooth irregular segment that joins
into a line, an arc or an oscillation, so the motion's regularity appears only late.

The irregular segment is a chain of clothoids (``C`` tokens: curvature changing linearly
with arc length, each inheriting position, heading, speed and curvature from the one
before, so the chain is G2), wandering with seeded curvature slopes. It lasts exactly
the observe window: the regular token starts at the first acting frame. The join is
G1 (position and velocity continuous) and G2 where the regular token's curvature allows:

* ``L``: the last clothoid straightens the path to zero curvature; the line continues
  at the same heading and speed (G2).
* ``A``: the last clothoid bends the curvature to ``turn / radius``; the arc continues
  with the same heading, speed and curvature (G2).
* ``H``: the last clothoid straightens the path; the oscillation passes its centre
  along the heading at the same speed (G2: the curvature of H there is 0).

Episode ``i`` of a slice draws only from ``Generator(PCG64(SeedSequence([seed, i])))``
with ``Generator.random`` (53 bits per double): first its choices (observe window,
object, size, hand, text; the regular family and, in a test set, the interception
setting cycle with ``i``), then motions. A motion whose path would leave the workspace
or the view, come within the resting hand's shadow, move faster than
:data:`MAX_SPEED`, or not be interceptable (:func:`pipeline.stages.episode.plan`'s
checks) is redrawn from the same generator, up to :data:`MAX_DRAWS` times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from generators.draws import SETTINGS, CommonChoices, common_choices, episode_rng, first_feasible, path_fits, uniform
from generators.grids import MAX_SPEED, OBJECT_NAMES, OBJECT_RADII, OBJECT_SIZES, OBJECT_TOPS
from generators.tracks import compile_track, end_state, evaluate
from schemas.errors import SpecError
from schemas.motion import ArcToken, ClothoidToken, HarmonicToken, LineToken, Motion, Track
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

#: Regular families the irregular segment joins into, in the order episodes cycle through.
REGULAR = ("L", "A", "H")
REGULAR_PHRASES = {"L": "straightening into a line", "A": "settling into a circle", "H": "settling into a swing"}
MAX_DRAWS = 64
#: Clothoids in the irregular segment (the last one shapes the join).
CLOTHOIDS = (3, 5)
#: Observe window (the irregular segment) in seconds.
OBSERVE_SECONDS = (1.2, 2.4)
SPEED = (0.6, 1.6)
#: Curvature slopes of the wandering clothoids (1/unit^2) and the starting curvature (1/unit).
SLOPE = 1.2
START_CURVATURE = 0.6
ARC_RADIUS = (0.7, 2.0)
HARMONIC_FREQUENCY = (0.2, 0.45)
TEXTS = (
    "Grasp the {object} {phrase}.",
    "Catch the {object} as it wanders, {phrase}.",
    "Track the {object} and grasp it once its motion becomes regular.",
)


def _chain(rng: np.random.Generator, family: str, observe_s: float) -> tuple[ClothoidToken, ...]:
    """The irregular clothoid chain lasting ``observe_s`` seconds (its last piece shapes the join)."""
    count = CLOTHOIDS[0] + int(rng.random() * (CLOTHOIDS[1] - CLOTHOIDS[0] + 1))
    weights = np.array([0.5 + rng.random() for _ in range(count)])
    durations = observe_s * weights / weights.sum()
    start = (uniform(rng, -2.0, 2.0), uniform(rng, 3.0, 6.0))
    heading = uniform(rng, -math.pi, math.pi)
    speed = uniform(rng, *SPEED)
    curvature = uniform(rng, -START_CURVATURE, START_CURVATURE)
    tokens = [ClothoidToken(curvature_slope=uniform(rng, -SLOPE, SLOPE), duration=float(durations[0]), start=start,
                            heading=heading, speed=speed, curvature=curvature)]
    for k in range(1, count - 1):
        tokens.append(ClothoidToken(curvature_slope=uniform(rng, -SLOPE, SLOPE), duration=float(durations[k])))
    tokens.append(ClothoidToken(curvature_slope=0.0, duration=float(durations[-1])))  # slope set by the join
    return tuple(tokens)


def _end_curvature(tokens: tuple[ClothoidToken, ...]) -> tuple[float, float]:
    """(curvature, speed) entering the last clothoid."""
    pieces = compile_track(Track(tokens[:-1])).pieces
    _, _, speed, kappa = end_state(pieces[-1])
    return kappa, speed


def irregular_motion(rng: np.random.Generator, family: str, observe_s: float, total_s: float) -> Motion:
    """A clothoid chain of ``observe_s`` seconds joined into a ``family`` token lasting to ``total_s``."""
    if family not in REGULAR:
        raise SpecError(f"regular family must be one of {list(REGULAR)}, got {family!r}")
    tokens = _chain(rng, family, observe_s)
    kappa, speed = _end_curvature(tokens)
    last = tokens[-1]
    radius = turn = 0.0
    target = 0.0
    if family == "A":
        radius = uniform(rng, *ARC_RADIUS)
        turn = 1.0 if kappa >= 0 else -1.0
        target = turn / radius
    length = speed * last.duration
    tokens = tokens[:-1] + (ClothoidToken(curvature_slope=(target - kappa) / length, duration=last.duration),)
    pieces = compile_track(Track(tokens)).pieces
    _, heading, speed, _ = end_state(pieces[-1])
    rest = total_s - observe_s
    regular: LineToken | ArcToken | HarmonicToken
    if family == "L":
        regular = LineToken(start=(0.0, 0.0), direction=heading, speed=speed, acceleration=0.0, duration=rest)
    elif family == "A":
        # position angle th on the circle, moving at +-w: the tangent (-sin, cos) * turn is the heading
        start_angle = heading - turn * math.pi / 2.0
        regular = ArcToken(centre=(0.0, 0.0), radius=radius, angular_velocity=speed / radius,
                           start_angle=start_angle, turn=int(turn), duration=rest)
    else:
        frequency = uniform(rng, *HARMONIC_FREQUENCY)
        amplitude = speed / (2.0 * math.pi * frequency)
        regular = HarmonicToken(centre=(0.0, 0.0), axis=heading, amplitude=amplitude, frequency=frequency,
                                phase=0.0, duration=rest)
    return Motion(Track(tokens + (regular,)))


def _fits(motion: Motion, seconds: float, radius: float, top: float) -> bool:
    """Workspace, view (the object's bounding box over the whole path), speed, rest-hand shadow."""
    if not path_fits(motion, seconds, radius, top):
        return False
    times = np.linspace(0.0, seconds, int(seconds * 200) + 2)
    velocity = evaluate(motion, times).velocity
    return float(np.hypot(velocity[:, 0], velocity[:, 1]).max()) <= MAX_SPEED


@dataclass(frozen=True)
class Choices:
    """The regular family the chain joins into, and the common choices."""

    family: str
    common: CommonChoices


def choices(seed: int, index: int, setting: str | None, cycle: int | None = None) -> tuple[Choices, np.random.Generator]:
    """Episode ``index``'s choices and the generator its motion attempts then draw from.

    The regular family cycles with ``cycle`` (default ``index``; a mixed test set passes
    the episode's place among its irregular ones); ``setting`` None cycles the three
    interception settings too (a test set). The choices come first in the stream, so
    counts and lengths are known without trying any motion."""
    rng = episode_rng(seed, index)
    cycle = index if cycle is None else cycle
    family = REGULAR[cycle % len(REGULAR)]
    chosen = setting or SETTINGS[(cycle // len(REGULAR)) % len(SETTINGS)]
    return Choices(family, common_choices(rng, chosen, OBSERVE_SECONDS, range(len(OBJECT_NAMES)), len(TEXTS))), rng


def irregular_spec(slice_name: str, seed: int, setting: str | None, index: int, cycle: int | None = None) -> EpisodeSpec:
    """Episode ``index`` of an irregular slice (module docstring)."""
    choice, rng = choices(seed, index, setting, cycle)
    c = choice.common
    name = c.object_name
    radius, top = float(OBJECT_RADII[c.object_index, c.size_index]), float(OBJECT_TOPS[c.object_index, c.size_index])

    def attempt() -> EpisodeSpec | None:
        motion = irregular_motion(rng, choice.family, c.observe_frames / FPS, c.num_frames / FPS)
        if not _fits(motion, c.num_frames / FPS, radius, top):
            return None
        return EpisodeSpec(
            slice=slice_name, episode_index=index, seed=seed, motion_type="irregular", motion=motion,
            object=name, object_size=float(OBJECT_SIZES[c.object_index, c.size_index]), hand=c.hand,
            rollout_format="observe-before-act", intercept_setting=c.setting, observe_frames=c.observe_frames,
            num_frames=c.num_frames,
            text=TEXTS[c.text].format(object=name.replace("_", " "), phrase=REGULAR_PHRASES[choice.family]),
        )

    return first_feasible(attempt, MAX_DRAWS, slice_name, index)
