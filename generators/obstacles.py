"""Obstacle-aware grasping (paper A.11): the target goes around a box on the table, and
the hand reaches it without touching any obstacle.

An episode's scene holds one obstacle the object turns around, and with probability
:data:`SECOND_CHANCE` a second, low one on the way between the resting hand and the
object. The object's motion is composed from existing tokens: a line ``L`` that meets
the circle around the first obstacle tangentially, an arc ``A`` about the obstacle's
centre (radius = the obstacle's footprint radius + the object's + a seeded gap) turning
a seeded angle, and a line ``L`` leaving tangentially (G1 at both joins, constant speed).
The arc starts inside the observe window, so the model sees the object start to turn.

The ground-truth hand (:func:`generators.interception.plan_episode`) lifts its approach
over the obstacles by the smallest bump that keeps :data:`schemas.obstacles.OBSTACLE_MARGIN`
from every one of them at every frame; episodes whose hand or object cannot keep that
margin (say the grasp would put a finger on the obstacle) are redrawn.

Episode ``i`` of a slice draws only from ``Generator(PCG64(SeedSequence([seed, i])))``:
its choices first (observe window, object, size, hand, text; in a test set the setting
cycles), then scenes, redrawn up to :data:`MAX_DRAWS` times until the object stays in the
workspace and the view, clear of the rest hand's shadow and of the obstacles, is not
hidden by an obstacle while observed, and the interception plans.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from generators.camera import in_view
from generators.clearance import object_clearance, obstacle_corners
from generators.draws import SETTINGS, CommonChoices, common_choices, episode_rng, first_feasible, path_fits, uniform
from generators.grids import OBJECT_NAMES, OBJECT_RADII, OBJECT_SIZES, OBJECT_TOPS
from generators.ground_truth import frame_times
from schemas.motion import ArcToken, LineToken, Motion
from schemas.obstacles import OBSTACLE_CATEGORIES, OBSTACLE_MARGIN, Obstacle
from schemas.scene import PALM_REST
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

MAX_DRAWS = 200
OBSERVE_SECONDS = (0.6, 1.2)
SPEED = (0.6, 1.4)
#: Angle the object turns around the obstacle (rad) and the gap between their footprints.
TURN = (math.pi / 3.0, 5.0 * math.pi / 6.0)
GAP = (0.25, 0.6)
#: Where the arc starts, as a fraction of the observe window.
ARC_START = (0.3, 0.9)
#: Scale of an obstacle against its category's nominal size.
SCALE = (0.8, 1.2)
#: Probability of a second obstacle between the resting hand and the object.
SECOND_CHANCE = 0.5
#: Categories of the obstacle the object goes around, and of the second (low) one.
AROUND = ("crate", "book", "brick")
ON_THE_WAY = ("book", "brick")
TEXTS = (
    "Grasp the {object} as it goes around the {obstacle}.",
    "Reach past the {obstacle} and catch the {object}.",
    "Pick up the moving {object} without touching the {obstacle}.",
)


@dataclass(frozen=True)
class Choices:
    """The common choices plus the obstacles' categories (the second may be absent)."""

    common: CommonChoices
    around: str
    second: str | None


def choices(seed: int, index: int, setting: str | None, cycle: int | None = None) -> tuple[Choices, np.random.Generator]:
    """Episode ``index``'s choices and the generator its scenes then draw from; ``setting``
    None cycles the interception settings with ``cycle`` (default ``index``)."""
    rng = episode_rng(seed, index)
    chosen = setting or SETTINGS[(index if cycle is None else cycle) % len(SETTINGS)]
    common = common_choices(rng, chosen, OBSERVE_SECONDS, range(len(OBJECT_NAMES)), len(TEXTS))
    around = AROUND[int(rng.random() * len(AROUND))]
    second = ON_THE_WAY[int(rng.random() * len(ON_THE_WAY))] if rng.random() < SECOND_CHANCE else None
    return Choices(common, around, second), rng


def _box(rng: np.random.Generator, category: str, centre: tuple[float, float]) -> Obstacle:
    nominal = OBSTACLE_CATEGORIES[category].half_extents
    k = uniform(rng, *SCALE)
    half = (round(nominal[0] * k, 4), round(nominal[1] * k, 4), round(nominal[2] * k, 4))
    return Obstacle(category, centre, half, yaw=uniform(rng, 0.0, math.pi))


def _footprint_radius(obstacle: Obstacle) -> float:
    return math.hypot(obstacle.half_extents[0], obstacle.half_extents[2])


def scene(rng: np.random.Generator, c: Choices, radius: float) -> tuple[Motion, tuple[Obstacle, ...]]:
    """A seeded obstacle layout and the object's path around the first obstacle."""
    seconds = c.common.num_frames / FPS
    observe_s = c.common.observe_frames / FPS
    first = _box(rng, c.around, (uniform(rng, -2.0, 2.0), uniform(rng, 3.0, 6.0)))
    arc_radius = _footprint_radius(first) + radius + uniform(rng, *GAP)
    speed = uniform(rng, *SPEED)
    turn = 1 if rng.random() < 0.5 else -1
    theta = uniform(rng, -math.pi, math.pi)
    angle = uniform(rng, *TURN)
    arc_start = uniform(rng, *ARC_START) * observe_s
    arc_s = min(arc_radius * angle / speed, seconds - arc_start)
    heading = theta + turn * math.pi / 2.0
    cx, cz = first.centre
    join = (cx + arc_radius * math.cos(theta), cz + arc_radius * math.sin(theta))
    start = (join[0] - math.cos(heading) * speed * arc_start, join[1] - math.sin(heading) * speed * arc_start)
    tokens: list[LineToken | ArcToken] = [
        LineToken(start=start, direction=heading, speed=speed, acceleration=0.0, duration=arc_start),
        ArcToken(centre=first.centre, radius=arc_radius, angular_velocity=speed / arc_radius, start_angle=theta,
                 turn=turn, duration=arc_s),
    ]
    rest = seconds - arc_start - arc_s
    if rest > 1e-6:
        tokens.append(LineToken(start=(0.0, 0.0), direction=heading + turn * angle, speed=speed, acceleration=0.0,
                                duration=rest))
    motion = Motion.of(*tokens)
    obstacles: tuple[Obstacle, ...] = (first,)
    if c.second is not None:
        target = motion_target(motion, seconds)
        f = uniform(rng, 0.35, 0.65)
        centre = (PALM_REST[0] + f * (target[0] - PALM_REST[0]) + uniform(rng, -0.4, 0.4),
                  PALM_REST[2] + f * (target[1] - PALM_REST[2]))
        obstacles += (_box(rng, c.second, centre),)
    return motion, obstacles


def motion_target(motion: Motion, seconds: float) -> tuple[float, float]:
    """The object's XZ position at ``seconds`` (where the second obstacle lines up)."""
    from generators.tracks import evaluate

    p = evaluate(motion, [seconds]).position[0]
    return float(p[0]), float(p[1])


def _fits(motion: Motion, obstacles: tuple[Obstacle, ...], seconds: float, radius: float, top: float) -> bool:
    if not path_fits(motion, seconds, radius, top):
        return False
    for o in obstacles:
        corners = obstacle_corners(o)
        if not in_view(corners[:, 0], corners[:, 1], corners[:, 2]).all():
            return False
    if len(obstacles) == 2:
        (a, b) = obstacles
        gap = math.dist(a.centre, b.centre) - _footprint_radius(a) - _footprint_radius(b)
        if gap < 0.3:
            return False
    return True


def obstacle_spec(slice_name: str, seed: int, setting: str | None, index: int, cycle: int | None = None) -> EpisodeSpec:
    """Episode ``index`` of an obstacle slice (module docstring)."""
    from generators.motion import object_pose

    choice, rng = choices(seed, index, setting, cycle)
    c = choice.common
    name = c.object_name
    radius, top = float(OBJECT_RADII[c.object_index, c.size_index]), float(OBJECT_TOPS[c.object_index, c.size_index])
    size = float(OBJECT_SIZES[c.object_index, c.size_index])
    seconds = c.num_frames / FPS

    def attempt() -> EpisodeSpec | None:
        motion, obstacles = scene(rng, choice, radius)
        if not _fits(motion, obstacles, seconds, radius, top):
            return None
        poses, _ = object_pose(motion, name, size, frame_times(c.num_frames))
        if object_clearance(name, size, poses, obstacles).min() < OBSTACLE_MARGIN:
            return None
        return EpisodeSpec(
            slice=slice_name, episode_index=index, seed=seed, motion_type="obstacle", motion=motion,
            object=name, object_size=size, hand=c.hand, rollout_format="observe-before-act",
            intercept_setting=c.setting, observe_frames=c.observe_frames, num_frames=c.num_frames,
            text=TEXTS[c.text].format(object=name.replace("_", " "), obstacle=choice.around), obstacles=obstacles,
        )

    return first_feasible(attempt, MAX_DRAWS, slice_name, index)
