"""The interception solver and the ground-truth hand plan of one episode.

Timeline (frames, ``a = spec.observe_frames``, ``i = spec.intercept_frame``):

* ``[0, a]`` the hand rests at :data:`generators.hand.REST_PALM` with open fingers
  (frame ``a`` is the first acting frame and still the rest pose);
* ``[a, i]`` the palm follows a ramp-cruise-ramp path (:func:`cruise_step`, plus the
  quintic's end-velocity and end-acceleration terms) from rest, with zero
  velocity and acceleration, to the hover point over the object's top at frame ``i``,
  arriving with the object's velocity and acceleration, so it never stops before
  arrival and joins the tracking motion with continuous velocity and acceleration;
  with obstacles in the scene the path is lifted by the smallest :func:`lift_bump` that
  keeps the hand :data:`~schemas.obstacles.OBSTACLE_MARGIN` from every one of them;
* ``[i, n)`` the palm tracks the hover point ``(x, top + hover, z)`` (the grasp design's
  hover, :data:`schemas.scene.PALM_HOVER` for the dataset's) of the
  moving object while the fingers close with a minimum-jerk profile from rest
  (frame ``i``) to :func:`generators.grasp.grasp_angles` (frame ``i + GRASP_FRAMES - 1``),
  then hold.

The palm keeps the rest orientation throughout (actions steer only its position), unless
a design turns it across a lying cylinder's axis (``heading``): then it turns about the
vertical along the approach (the same ramp-cruise-ramp quintic, arriving with the heading's
rate) and follows the heading from the intercept frame on (the ground truth's heading is
constant: :func:`generators.ground_truth.palm_heading`), or turns it by the wrist reflex
(:mod:`generators.wrist`: from the first closing frame, as the hand's own rule).

Action: ``action[t] = (palm_xyz[t + 1], joint_angles[t + 1])``, the targets issued at
frame ``t`` and reached at frame ``t + 1``; the last frame repeats its own state.
During the observe window the action is therefore the rest pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from generators.camera import points_in_view
from generators.grasp import DEFAULT_DESIGN, GraspDesign, grasp_angles, grasp_hover, lowest_fingertip_offset
from generators.hand import JOINT_LOWER, JOINT_UPPER, REST_JOINTS, REST_PALM, fingertip_positions
from schemas.errors import InfeasibleError
from schemas.objects import object_category
from schemas.obstacles import OBSTACLE_MARGIN
from schemas.scene import GRASP_FRAMES, PALM_HIGH, PALM_LOW, PHASES, WORKSPACE_X, WORKSPACE_Z
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

#: Fastest palm speed a plan may ask for (units/s; 35 = 3.5 m/s).
MAX_PALM_SPEED = 35.0
#: Every approach step must be longer than this (units): no stagnation before arrival.
MIN_APPROACH_STEP = 1e-4
#: Lowest a fingertip may go (the table top is Y = 0).
MIN_FINGERTIP_HEIGHT = 0.0
#: How deep the planned hand may go under the table top, and the palm and wrist into a
#: flying object (units): less than the hand body's ``TOUCH`` (0.05,
#: :mod:`generators.hand_body`), so the body passes the plan unchanged.
MAX_DEPTH = 0.04
#: For a flying object: the fractions of its vertical velocity and acceleration at the
#: intercept that the palm's approach arrives with, tried in order (for each rise of
#: :data:`LIFT_RISES`) until the approach keeps the hand out of the table and the palm out of
#: the ball. Matching a ball that rises (or falls under gravity's -98.1 units/s^2) fully can
#: take the palm units under the table on the way (test-complex: down to Y = -4.6) or
#: through the ball; the palm then joins the hover point with a velocity change the hand
#: body allows in one frame.
VERTICAL_MATCH = (1.0, 0.75, 0.5, 0.25, 0.0)
_PHASE = {name: i for i, name in enumerate(PHASES)}


@dataclass(frozen=True)
class HandPlan:
    """The ground-truth hand of one episode, per frame (float64 arrays)."""

    phase: np.ndarray  # (n,) int8 indices into PHASES
    palm_pose: np.ndarray  # (n, 6)
    joint_angles: np.ndarray  # (n, 15)
    action: np.ndarray  # (n, 18)
    grasp_angles: np.ndarray  # (15,)
    hover: np.ndarray  # (n, 3) the hover point over the object's top
    intercept_frame: int

    @property
    def num_frames(self) -> int:
        return len(self.phase)


def minimum_jerk(s: np.ndarray) -> np.ndarray:
    """Rest-to-rest minimum-jerk profile on [0, 1]: 10 s^3 - 15 s^4 + 6 s^5 (clipped)."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


#: Fraction of the approach spent speeding up (and, symmetrically, slowing down).
APPROACH_RAMP = 0.15


def cruise_step(s: np.ndarray, ramp: float) -> np.ndarray:
    """Smooth step on [0, 1] whose speed ramps up over ``ramp``, cruises, and ramps down.

    The speed is the minimum-jerk step S(x) = 10x^3 - 15x^4 + 6x^5 on the ramps and 1 in
    between, normalised so the step goes 0 -> 1: zero velocity and acceleration at both
    ends, continuous acceleration everywhere. Against a bell-shaped minimum-jerk speed it
    keeps the palm's step lengths nearly even (the paper's Q_smooth), with no stop.
    """
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, 1.0)

    def area(x: np.ndarray) -> np.ndarray:  # integral of S from 0 to x
        return x**4 * (2.5 + x * (-3.0 + x))

    up = ramp * area(np.minimum(s, ramp) / ramp)
    cruise = np.clip(s - ramp, 0.0, 1.0 - 2.0 * ramp)
    down = ramp * (0.5 - area(np.clip((1.0 - s) / ramp, 0.0, 1.0)))
    down = np.where(s > 1.0 - ramp, down, 0.0)
    return (up + cruise + down) / (1.0 - ramp)


def quintic(start: np.ndarray, end: np.ndarray, end_velocity: np.ndarray, end_acceleration: np.ndarray,
            duration: float, s: np.ndarray) -> np.ndarray:
    """Quintic from ``start`` at rest to ``end`` with the given end velocity and acceleration.

    ``s`` (m,) is normalised time in [0, 1]; returns (m, d) positions.
    """
    s = np.asarray(s, dtype=np.float64)[:, None]
    s3 = s * s * s
    rest = cruise_step(s, APPROACH_RAMP)
    vel = s3 * (-4.0 + s * (7.0 - 3.0 * s))
    acc = s3 * (0.5 + s * (-1.0 + 0.5 * s))
    return (
        start
        + rest * (end - start)
        + vel * (end_velocity * duration)
        + acc * (end_acceleration * duration * duration)
    )


def phases(spec: EpisodeSpec) -> np.ndarray:
    """(n,) phase index of every frame."""
    out = np.full(spec.num_frames, _PHASE["hold"], dtype=np.int8)
    out[: spec.observe_frames] = _PHASE["observe"]
    out[spec.observe_frames : spec.intercept_frame] = _PHASE["approach"]
    out[spec.intercept_frame : spec.intercept_frame + GRASP_FRAMES] = _PHASE["grasp"]
    return out


def closure_profile(num_frames: int, intercept_frame: int) -> np.ndarray:
    """(n,) fraction of the grasp closed at each frame: 0 until ``intercept_frame``, 1 from
    ``intercept_frame + GRASP_FRAMES - 1`` on, minimum jerk between."""
    k = np.arange(num_frames, dtype=np.float64) - intercept_frame
    return minimum_jerk(k / (GRASP_FRAMES - 1))




#: Heights (units) tried, in order, for the approach's lift over obstacles.
LIFT_RISES = tuple(0.25 * k for k in range(0, 25))


def lift_bump(s: np.ndarray) -> np.ndarray:
    """64 s^3 (1 - s)^3: 0 at both ends with zero velocity and acceleration, 1 at s = 1/2.
    Added to the approach's height, it lifts the palm over obstacles without changing its
    start, its arrival or their continuity."""
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, 1.0)
    return 64.0 * (s * (1.0 - s)) ** 3


def _clearing_rise(spec: EpisodeSpec, palm: np.ndarray, joints: np.ndarray, a: int, i: int, approach,
                   design: GraspDesign = DEFAULT_DESIGN, turn: np.ndarray | None = None) -> float:
    """The smallest rise of :data:`LIFT_RISES` whose lifted approach keeps the hand
    :data:`OBSTACLE_MARGIN` from every obstacle at every frame; InfeasibleError if none
    does (or the margin is broken after arrival, where the palm tracks the object)."""
    from generators.clearance import hand_clearance

    rest = np.repeat(REST_PALM[None, 3:], len(palm), axis=0) if turn is None else turn
    geometry = design.hand
    after = hand_clearance(np.concatenate([palm[i:], rest[i:]], axis=1), joints[i:], spec.hand, spec.obstacles, geometry)
    if after.min() < OBSTACLE_MARGIN:
        k = i + int(np.argmin(after))
        raise InfeasibleError(f"the hand would come within {after.min():.3f} units of an obstacle at frame {k}")
    before = hand_clearance(np.concatenate([palm[: a + 1], rest[: a + 1]], axis=1), joints[: a + 1], spec.hand,
                            spec.obstacles, geometry)
    if before.min() < OBSTACLE_MARGIN:
        raise InfeasibleError(f"the resting hand is within {before.min():.3f} units of an obstacle")
    for rise in LIFT_RISES:
        path = approach(rise)
        clear = hand_clearance(np.concatenate([path, rest[a : i + 1]], axis=1), joints[a : i + 1], spec.hand,
                               spec.obstacles, geometry)
        if clear.min() >= OBSTACLE_MARGIN:
            return rise
    raise InfeasibleError(f"no lift up to {LIFT_RISES[-1]} units takes the hand over the obstacles")


def _airborne_approach(spec: EpisodeSpec, palm: np.ndarray, turn: np.ndarray, joints: np.ndarray, a: int, i: int,
                       approach, centres: np.ndarray, radius: float,
                       design: GraspDesign = DEFAULT_DESIGN) -> tuple[float, float]:
    """The smallest rise of :data:`LIFT_RISES`, then the first of :data:`VERTICAL_MATCH`, whose
    approach toward a flying ball (``centres`` (n, 3), ``radius``) keeps the palm in
    :data:`schemas.scene.PALM_BOX`, the hand at most :data:`MAX_DEPTH` under the table and
    the palm and wrist at most that deep in the ball at every acting frame; InfeasibleError
    naming the first candidate's worst frame if none does."""
    from generators.clearance import hand_table_depth, palm_sphere_depth

    path = palm.copy()
    low, high = np.asarray(PALM_LOW), np.asarray(PALM_HIGH)
    worst: tuple[str, float, int] | None = None
    for rise in LIFT_RISES:
        for match in VERTICAL_MATCH:
            path[a : i + 1] = approach(rise, match)
            pose = np.concatenate([path[a:], turn[a:]], axis=1)
            table = hand_table_depth(pose, joints[a:], spec.hand, design.hand)
            ball = palm_sphere_depth(pose, centres[a:], radius)
            inside = np.all((path[a:] >= low) & (path[a:] <= high))
            if inside and max(table.max(), ball.max()) <= MAX_DEPTH:
                return rise, match
            if worst is None:
                into = ("under the table", table) if table.max() >= ball.max() else ("into the ball", ball)
                worst = (into[0], float(into[1].max()), a + int(np.argmax(into[1])))
    assert worst is not None
    raise InfeasibleError(f"the approach would take the hand {worst[1]:.2f} units {worst[0]} at frame {worst[2]}")


def _check_in_view(name: str, points: np.ndarray) -> None:
    inside = points_in_view(points)
    if not inside.all():
        raise InfeasibleError(f"the {name} leaves the camera's view at frame {int(np.argmin(inside))}")


def _check_hand_in_view(palm: np.ndarray, fingertips: np.ndarray) -> None:
    """Some of the hand (its palm centre or a fingertip) is in view at every frame; at rest
    the palm sits at the image's bottom edge with the fingers in view."""
    seen = points_in_view(palm) | points_in_view(fingertips).any(axis=1)
    if not seen.all():
        raise InfeasibleError(f"the hand leaves the camera's view at frame {int(np.argmin(seen))}")


def plan_episode(
    spec: EpisodeSpec,
    object_xz: np.ndarray,
    object_velocity_xz: np.ndarray,
    object_acceleration_xz: np.ndarray,
    elevation: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    design: GraspDesign = DEFAULT_DESIGN,
    yaw: float = 0.0,
    heading: np.ndarray | None = None,
    approach_turn: bool = True,
) -> HandPlan:
    """Solve the interception of ``spec`` and plan the hand over its ``n`` frames.

    The object's XZ position, velocity and acceleration are given at the frame times
    (arrays (n, 2)); ``elevation`` is its height above its resting height with the
    height's rate and acceleration (arrays (n,), :mod:`generators.ballistics`), None for
    an object on the table. ``design`` is the grasp (:class:`generators.grasp.GraspDesign`),
    ``yaw`` a lying cylinder's axis at the grasp (:func:`generators.grasp.cylinder_yaw`);
    ``heading`` (n,) the palm's turn about the vertical (its pitch) at every frame, followed
    from the intercept frame on, None to keep the rest orientation; with ``approach_turn``
    False it is the turn at every frame as given (the wrist reflex's, :mod:`generators.wrist`)
    and ``yaw`` is already relative to the palm.
    The hover point rises with the object, and the palm arrives
    with its 3D velocity and acceleration. Raises :class:`InfeasibleError` naming the reason when the target
    leaves the workspace or the view, the palm would have to move faster than
    :data:`MAX_PALM_SPEED` or would stall before arrival, or the fingers would hit the table.
    """
    n = spec.num_frames
    obj = np.asarray(object_xz, dtype=np.float64)
    vel = np.asarray(object_velocity_xz, dtype=np.float64)
    acc = np.asarray(object_acceleration_xz, dtype=np.float64)
    for name, arr in (("positions", obj), ("velocities", vel), ("accelerations", acc)):
        if arr.shape != (n, 2) or not np.isfinite(arr).all():
            raise InfeasibleError(f"object {name} must be finite with shape ({n}, 2), got {arr.shape}")
    a, i = spec.observe_frames, spec.intercept_frame
    frames = np.arange(n)
    lift, lift_v, lift_a = (np.zeros(n),) * 3 if elevation is None else (np.asarray(e, dtype=np.float64) for e in elevation)
    if any(e.shape != (n,) or not np.isfinite(e).all() for e in (lift, lift_v, lift_a)):
        raise InfeasibleError(f"object elevations must be finite with shape ({n},)")

    eps = 1e-9
    outside = (
        (obj[:, 0] < WORKSPACE_X[0] - eps)
        | (obj[:, 0] > WORKSPACE_X[1] + eps)
        | (obj[:, 1] < WORKSPACE_Z[0] - eps)
        | (obj[:, 1] > WORKSPACE_Z[1] + eps)
    )
    if outside.any():
        k = int(np.argmax(outside))
        raise InfeasibleError(
            f"the object leaves the workspace at frame {k} (x={obj[k, 0]:.3f}, z={obj[k, 1]:.3f})"
        )

    cat = object_category(spec.object)
    centre_y = cat.half_height(spec.object_size)
    turn = np.repeat(REST_PALM[None, 3:], n, axis=0)
    if heading is not None:
        heading = np.asarray(heading, dtype=np.float64)
        if heading.shape != (n,) or not np.isfinite(heading).all():
            raise InfeasibleError(f"the palm heading must be finite with shape ({n},), got {heading.shape}")
        if approach_turn:
            step = np.diff(heading[i - 1 : i + 2]) * FPS if 0 < i < n - 1 else np.zeros(2)
            end = (np.array([step.mean()]), np.array([(step[1] - step[0]) * FPS]))
            turn[a : i + 1, 1] = quintic(np.zeros(1), heading[i : i + 1], *end, (i - a) / FPS,
                                         (frames[a : i + 1] - a) / (i - a))[:, 0]
            turn[i:, 1] = heading[i:]
            yaw = yaw - float(heading[min(i + GRASP_FRAMES - 1, n - 1)])
        else:
            turn[:, 1] = heading
    hover_y = 2.0 * centre_y + grasp_hover(spec.object, spec.object_size, spec.hand, design, yaw)
    hover = np.column_stack([obj[:, 0], hover_y + lift, obj[:, 1]])
    _check_in_view("object", np.column_stack([obj[:, 0], centre_y + lift, obj[:, 1]]))

    grasp = grasp_angles(spec.object, spec.object_size, spec.hand, design, yaw)
    if np.any(grasp < JOINT_LOWER) or np.any(grasp > JOINT_UPPER):
        raise InfeasibleError(f"the grasp of {spec.object} (size {spec.object_size}) breaks a joint limit")
    closure = closure_profile(n, i)
    joints = REST_JOINTS + closure[:, None] * (grasp - REST_JOINTS)

    duration = (i - a) / FPS
    s = (frames[a : i + 1] - a) / (i - a)
    end_vel = np.array([vel[i, 0], lift_v[i], vel[i, 1]])
    end_acc = np.array([acc[i, 0], lift_a[i], acc[i, 1]])

    def approach(at: np.ndarray, rise: float, match: float = 1.0) -> np.ndarray:
        scale = np.array([1.0, match, 1.0])
        path = quintic(REST_PALM[:3], hover[i], end_vel * scale, end_acc * scale, duration, at)
        path[:, 1] += rise * lift_bump(at)
        return path

    rise, match = 0.0, 1.0
    palm = np.repeat(REST_PALM[None, :3], n, axis=0)
    palm[i:] = hover[i:]
    palm[a : i + 1] = approach(s, 0.0)
    if elevation is not None:  # on the table the approach's height is monotone: it cannot dip
        centres = np.column_stack([obj[:, 0], centre_y + lift, obj[:, 1]])
        rise, match = _airborne_approach(spec, palm, turn, joints, a, i, lambda r, m: approach(s, r, m), centres,
                                         centre_y, design)
        palm[a : i + 1] = approach(s, rise, match)
    if spec.obstacles:
        rise = _clearing_rise(spec, palm, joints, a, i, lambda r: approach(s, r, match), design,
                              None if heading is None else turn)
        palm[a : i + 1] = approach(s, rise, match)

    steps = np.linalg.norm(np.diff(palm[a : i + 1], axis=0), axis=1)
    if steps.min() <= MIN_APPROACH_STEP:
        k = a + int(np.argmin(steps))
        raise InfeasibleError(f"the palm would stall before arrival at frame {k} (step {steps.min():.2e})")
    # Peak speed of the analytic approach, sampled finely between frames.
    fine = np.linspace(0.0, 1.0, 8 * (i - a) + 1)
    path = approach(fine, rise, match)
    speed = np.linalg.norm(np.diff(path, axis=0), axis=1).max() / (duration / (len(fine) - 1))
    if speed > MAX_PALM_SPEED:
        raise InfeasibleError(f"the interception needs a palm speed of {speed:.1f} units/s (> {MAX_PALM_SPEED})")

    palm_pose = np.concatenate([palm, turn], axis=1)
    _check_hand_in_view(palm, fingertip_positions(palm_pose, joints, spec.hand, design.hand))
    lowest = hover_y + lowest_fingertip_offset(spec.object, spec.object_size, spec.hand, design, yaw)
    if lowest < MIN_FINGERTIP_HEIGHT:
        raise InfeasibleError(f"the fingers would go through the table (fingertip height {lowest:.3f})")

    state = np.concatenate([palm, joints], axis=1)
    action = np.concatenate([state[1:], state[-1:]], axis=0)
    return HandPlan(phases(spec), palm_pose, joints, action, grasp, hover, i)
