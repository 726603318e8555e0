"""Projectile interception (paper A.11): the target flies and bounces, the hand catches it
in the air.

An episode's motion is one ``P`` token (:mod:`generators.ballistics`): a ball (the
sphere categories: tennis ball, baseball, orange) enters the view in flight at a seeded
height, with a seeded upward speed and a horizontal velocity, under standard gravity
(9.81 m/s^2 = 98.1 units/s^2), and bounces on the table with a seeded restitution of a
lively ball. Real gravity makes a flight in view short (a 40 cm drop lasts 0.29 s), so
the hand meets the ball in one of its bounces: at the interception frame it must be in
the air (its bottom at least :data:`MIN_AIR` above the table), and the hand arrives over
it from above with its 3D velocity. Its start is drawn where the whole horizontal path
stays in the workspace.

Episode ``i`` of a slice draws only from ``Generator(PCG64(SeedSequence([seed, i])))``:
first its choices (observe window, object, size, hand, text; in a test set the setting
cycles), then flights, redrawn until the object stays in the workspace and the view,
clear of the resting hand's shadow, is airborne at the interception frame and the
interception plans (:func:`pipeline.stages.episode.plan`), up to :data:`MAX_DRAWS` times.
"""

from __future__ import annotations

import math

import numpy as np

from generators.ballistics import elevation
from generators.draws import SETTINGS, CommonChoices, common_choices, episode_rng, first_feasible, path_fits, uniform
from generators.grids import OBJECT_NAMES, OBJECT_RADII, OBJECT_SIZES
from generators.visibility import rest_shadow_z
from schemas.motion import STANDARD_GRAVITY, Motion, ProjectileToken
from schemas.objects import OBJECTS
from schemas.scene import INTERCEPT_SECONDS, WORKSPACE_X, WORKSPACE_Z
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

MAX_DRAWS = 200
#: Observe window (seconds): the flight shown before the hand may act.
OBSERVE_SECONDS = (0.4, 0.8)
#: Launch: elevation of the centre above its resting height, upward speed, horizontal speed.
LAUNCH_HEIGHT = (1.0, 3.0)
LAUNCH_UP_SPEED = (0.0, 8.0)
HORIZONTAL_SPEED = (0.4, 2.0)
#: Coefficient of restitution (a tennis ball's is about 0.75).
RESTITUTION = (0.7, 0.88)
#: Objects thrown: the balls (those whose shape rolls as a ball).
BALLS = tuple(k for k, name in enumerate(OBJECT_NAMES) if OBJECTS[name].geometry.roll_mode(OBJECTS[name].lying) == "ball")
#: Lowest the object's bottom may be above the table at the interception frame (units).
MIN_AIR = 0.2
TEXTS = (
    "Catch the flying {object}.",
    "Grab the {object} out of the air.",
    "Intercept the {object} as it bounces.",
)


def choices(seed: int, index: int, setting: str | None, cycle: int | None = None) -> tuple[CommonChoices, np.random.Generator]:
    """Episode ``index``'s choices and the generator its flights then draw from; ``setting``
    None cycles the interception settings with ``cycle`` (default ``index``)."""
    rng = episode_rng(seed, index)
    chosen = setting or SETTINGS[(index if cycle is None else cycle) % len(SETTINGS)]
    return common_choices(rng, chosen, OBSERVE_SECONDS, BALLS, len(TEXTS)), rng


def flight(rng: np.random.Generator, seconds: float, margin: float) -> Motion | None:
    """A seeded throw lasting ``seconds`` whose horizontal path keeps ``margin`` inside the
    workspace, or None when its displacement cannot fit (the caller redraws)."""
    heading = uniform(rng, -math.pi, math.pi)
    speed = uniform(rng, *HORIZONTAL_SPEED)
    vx, vz = speed * math.cos(heading), speed * math.sin(heading)
    up, height, restitution = (uniform(rng, *r) for r in (LAUNCH_UP_SPEED, LAUNCH_HEIGHT, RESTITUTION))
    low_z = max(WORKSPACE_Z[0], rest_shadow_z()) + margin
    ranges = []
    for d, (low, high) in ((vx * seconds, (WORKSPACE_X[0] + margin, WORKSPACE_X[1] - margin)),
                           (vz * seconds, (low_z, WORKSPACE_Z[1] - margin))):
        ranges.append((low + max(0.0, -d), high - max(0.0, d)))
    if any(a >= b for a, b in ranges):
        return None
    start = (uniform(rng, *ranges[0]), uniform(rng, *ranges[1]))
    token = ProjectileToken(start=start, velocity=(vx, up, vz), duration=seconds, height=height,
                            gravity=STANDARD_GRAVITY, restitution=restitution)
    return Motion.of(token)


def _fits(motion: Motion, seconds: float, radius: float, intercept_s: float) -> bool:
    if not path_fits(motion, seconds, radius):
        return False
    return float(elevation(motion, [intercept_s]).height[0]) >= MIN_AIR


def projectile_spec(slice_name: str, seed: int, setting: str | None, index: int, cycle: int | None = None) -> EpisodeSpec:
    """Episode ``index`` of a projectile slice (module docstring)."""
    c, rng = choices(seed, index, setting, cycle)
    name = c.object_name
    radius = float(OBJECT_RADII[c.object_index, c.size_index])
    seconds = c.num_frames / FPS
    intercept_s = (c.observe_frames + round(INTERCEPT_SECONDS[c.setting] * FPS)) / FPS

    def attempt() -> EpisodeSpec | None:
        motion = flight(rng, seconds, radius)
        if motion is None or not _fits(motion, seconds, radius, intercept_s):
            return None
        return EpisodeSpec(
            slice=slice_name, episode_index=index, seed=seed, motion_type="projectile", motion=motion,
            object=name, object_size=float(OBJECT_SIZES[c.object_index, c.size_index]), hand=c.hand,
            rollout_format="observe-before-act", intercept_setting=c.setting, observe_frames=c.observe_frames,
            num_frames=c.num_frames, text=TEXTS[c.text].format(object=name.replace("_", " ")),
        )

    return first_feasible(attempt, MAX_DRAWS, slice_name, index)
