"""The ground-truth plan of an episode: the object's trajectory at the frame times, the
observability check of the observe window and the hand's interception plan.

The slice generators call :func:`plan` to keep only interceptable episodes; the episode
stage (:mod:`pipeline.stages.episode`) turns the plan into the recorded frames.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from generators import motion
from generators.ballistics import elevation
from generators.grasp import DEFAULT_DESIGN, GraspDesign, cylinder_yaw, grasp_angles
from generators.interception import HandPlan, closure_profile, plan_episode
from generators.visibility import first_hidden_frame
from generators.wrist import wrist_clear_heights, wrist_headings
from schemas.errors import InfeasibleError
from schemas.objects import object_category
from schemas.scene import GRASP_FRAMES, GRASP_RATIO, MIN_OBSERVE_VISIBLE
from schemas.spec import EpisodeSpec
from schemas.versions import FPS


def frame_times(num_frames: int) -> np.ndarray:
    """Timestamps ``k / FPS`` of frames ``0 .. num_frames - 1``, computed, never summed."""
    return np.arange(num_frames, dtype=np.float64) / FPS


def object_trajectory(spec: EpisodeSpec) -> tuple[np.ndarray, np.ndarray, motion.MotionSample]:
    """The object's poses (n, 7), world velocities (n, 3) and XZ motion sample at the frame times."""
    t = frame_times(spec.num_frames)
    poses, velocity = motion.object_pose(spec.motion, object_category(spec.object), spec.object_size, t)
    return poses, velocity, motion.evaluate(spec.motion, t)


def check_observable(spec: EpisodeSpec, poses: np.ndarray, design: GraspDesign = DEFAULT_DESIGN) -> None:
    """Refuse an episode whose object is not shown enough (in the image and unhidden by the
    resting hand) in some observe frame: the protocol promises the model sees the motion."""
    hidden = first_hidden_frame(spec.object, spec.object_size, spec.hand, poses[: spec.observe_frames], spec.obstacles,
                                design.hand)
    if hidden is not None:
        frame, fraction = hidden
        raise InfeasibleError(
            f"the object is only {fraction:.0%} visible at observe frame {frame} (the resting hand, an "
            f"obstacle or the image edge hides the rest; at least {MIN_OBSERVE_VISIBLE:.0%} must show)"
        )


def grasp_frame(spec: EpisodeSpec) -> int:
    """The frame the ground truth's grasp first counts as closed (every joint at GRASP_RATIO
    of its grasp angle, :func:`schemas.events.grasp_closed`), where the hold test starts: the
    intercept frame plus the first step of the closing profile that reaches GRASP_RATIO
    (the last frame if sooner)."""
    closure = closure_profile(spec.intercept_frame + GRASP_FRAMES, spec.intercept_frame)
    return min(int(np.argmax(closure >= GRASP_RATIO)), spec.num_frames - 1)


def grasp_yaw(spec: EpisodeSpec, poses: np.ndarray) -> float:
    """A lying cylinder's axis yaw (:func:`generators.grasp.cylinder_yaw`) at
    :func:`grasp_frame` of the object's ``poses`` (n, 7); 0 for other objects."""
    if not object_category(spec.object).lying:
        return 0.0
    return cylinder_yaw(poses[grasp_frame(spec), 3:])


def palm_heading(spec: EpisodeSpec, poses: np.ndarray) -> np.ndarray:
    """(n,) the palm's turn about the vertical (its pitch) that lays its X axis along a lying
    cylinder's axis at :func:`grasp_frame` of ``poses``, within a quarter turn of the rest
    orientation, at every frame: the palm turns once, on the approach, and keeps that
    heading (a cylinder rolling on a curve turns with its path, fastest where it slows to
    turn back, up to 25 rad/s in test-1k's harmonic paths; following it would turn the palm
    as fast)."""
    yaw = cylinder_yaw(poses[grasp_frame(spec), 3:])
    return np.full(len(poses), yaw - np.pi * np.round(yaw / np.pi))


def episode_grasp(spec: EpisodeSpec, design: GraspDesign = DEFAULT_DESIGN) -> np.ndarray:
    """(15,) the ground truth's grasp angles of ``spec`` as ``design`` grasps (what
    :func:`plan` puts in :attr:`HandPlan.grasp_angles`), without planning, except for a
    lying cylinder under a wrist-reflex design (its grasp depends on the heading the
    reflex reaches: the plan's own)."""
    if not object_category(spec.object).lying or not (design.as_placed or design.turn_to_axis or design.wrist_reflex):
        return grasp_angles(spec.object, spec.object_size, spec.hand, design)
    if design.wrist_reflex:  # sized for the heading the reflex reaches: the plan's own
        try:
            return plan(spec, design)[0].grasp_angles
        except InfeasibleError:  # no ground truth: as if the palm were across the axis
            pass
    poses = motion.object_orientation(spec.motion, spec.object, spec.object_size, frame_times(spec.num_frames))
    yaw = cylinder_yaw(poses[grasp_frame(spec)])
    if design.turn_to_axis or design.wrist_reflex:
        yaw -= float(palm_heading(spec, np.concatenate([np.zeros((len(poses), 3)), poses], axis=1))[grasp_frame(spec)])
    return grasp_angles(spec.object, spec.object_size, spec.hand, design, yaw)


#: Most plans :func:`wrist_plan` tries before its turn and its grasp agree.
WRIST_ROUNDS = 5


def _recorded(values: np.ndarray) -> np.ndarray:
    return np.asarray(values).astype(np.float32).astype(np.float64)


def wrist_plan(spec: EpisodeSpec, design: GraspDesign, sample: motion.MotionSample, lift, poses: np.ndarray) -> HandPlan:
    """The plan of a lying cylinder whose palm the wrist reflex turns (:mod:`generators.wrist`):
    the reflex's headings over the plan's own recorded (float32) states, and the grasp sized
    for the cylinder's axis relative to the palm at :func:`grasp_frame`, re-planned until the
    two agree (the grasp's size decides the frame the reflex starts on; InfeasibleError if
    they do not agree in :data:`WRIST_ROUNDS` plans); the palm raised where the wrist,
    not yet turned across the cylinder, would enter it (:func:`generators.wrist.wrist_clear_heights`)."""
    frame, axis = grasp_frame(spec), grasp_yaw(spec, poses)
    heading = np.zeros(spec.num_frames)
    for _ in range(WRIST_ROUNDS):
        hand = plan_episode(spec, sample.position, sample.velocity, sample.acceleration, lift, design,
                            axis - float(heading[frame]), heading, approach_turn=False)
        turned = wrist_headings(_recorded(hand.palm_pose[:, :3]), _recorded(hand.joint_angles), _recorded(poses),
                                spec.object, np.asarray(design.synergy_end))
        if np.array_equal(turned, heading):
            return _wrist_clear(spec, hand, poses)
        heading = turned
    raise InfeasibleError(f"the wrist reflex's turn and the grasp do not agree after {WRIST_ROUNDS} plans")


def _wrist_clear(spec: EpisodeSpec, hand: HandPlan, poses: np.ndarray) -> HandPlan:
    """The plan with the palm raised where the wrist would enter the object, at the frame's
    heading or at the frame before's (a body moves the palm, then turns it)."""
    palm = hand.palm_pose.copy()
    before = np.r_[palm[:1, 4], palm[:-1, 4]]
    palm[:, 1] = np.maximum(wrist_clear_heights(palm, palm[:, 4], spec.object, spec.object_size, poses),
                            wrist_clear_heights(palm, before, spec.object, spec.object_size, poses))
    if np.array_equal(palm, hand.palm_pose):
        return hand
    state = np.concatenate([palm[:, :3], hand.joint_angles], axis=1)
    return dataclasses.replace(hand, palm_pose=palm, action=np.concatenate([state[1:], state[-1:]], axis=0))


def plan(spec: EpisodeSpec, design: GraspDesign = DEFAULT_DESIGN) -> tuple[HandPlan, np.ndarray, np.ndarray]:
    """The ground-truth hand plan of ``spec`` (grasping as ``design``) with the object's
    poses and velocities.

    Raises :class:`InfeasibleError` when the object would be hidden while observed or the
    interception cannot be planned."""
    poses, velocity, sample = object_trajectory(spec)
    check_observable(spec, poses, design)
    lift = None
    if spec.motion.airborne:
        e = elevation(spec.motion, frame_times(spec.num_frames))
        lift = (e.height, e.velocity, e.acceleration)
    if design.wrist_reflex and object_category(spec.object).lying:
        return wrist_plan(spec, design, sample, lift, poses), poses, velocity
    heading = palm_heading(spec, poses) if design.turn_to_axis and object_category(spec.object).lying else None
    hand = plan_episode(spec, sample.position, sample.velocity, sample.acceleration, lift, design, grasp_yaw(spec, poses),
                        heading)
    return hand, poses, velocity
