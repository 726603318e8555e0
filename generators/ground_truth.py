"""The ground-truth plan of an episode: the object's trajectory at the frame times, the
observability check of the observe window and the hand's interception plan.

The slice generators call :func:`plan` to keep only interceptable episodes; the episode
stage (:mod:`pipeline.stages.episode`) turns the plan into the recorded frames.
"""

from __future__ import annotations

import numpy as np

from generators import motion
from generators.ballistics import elevation
from generators.grasp import DEFAULT_DESIGN, GraspDesign, cylinder_yaw, grasp_angles
from generators.interception import HandPlan, closure_profile, plan_episode
from generators.visibility import first_hidden_frame
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
    :func:`plan` puts in :attr:`HandPlan.grasp_angles`), without planning."""
    if not object_category(spec.object).lying or not (design.as_placed or design.turn_to_axis):
        return grasp_angles(spec.object, spec.object_size, spec.hand, design)
    poses = motion.object_orientation(spec.motion, spec.object, spec.object_size, frame_times(spec.num_frames))
    yaw = cylinder_yaw(poses[grasp_frame(spec)])
    if design.turn_to_axis:
        yaw -= float(palm_heading(spec, np.concatenate([np.zeros((len(poses), 3)), poses], axis=1))[grasp_frame(spec)])
    return grasp_angles(spec.object, spec.object_size, spec.hand, design, yaw)


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
    heading = palm_heading(spec, poses) if design.turn_to_axis and object_category(spec.object).lying else None
    hand = plan_episode(spec, sample.position, sample.velocity, sample.acceleration, lift, design, grasp_yaw(spec, poses),
                        heading)
    return hand, poses, velocity
