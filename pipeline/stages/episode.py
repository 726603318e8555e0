"""The episode stage: ``EpisodeSpec`` -> per-frame states and actions, no rendering.

``episode(spec)`` samples the object's motion at the frame times ``k / FPS``, solves
the interception (:func:`generators.interception.plan_episode`), runs the hand's
forward kinematics and measures the events (palm XZ distance to the object's centre,
fingertip distance to its surface). The build records its output; the closed loop
uses :func:`assemble_frames` to turn the states its policy produced into the same
arrays.

``pipeline.episode(spec)`` is this module's :func:`episode`, loaded on first call.
"""

from __future__ import annotations

import numpy as np

from generators import motion
from generators.ballistics import elevation
from generators.clearance import hand_clearance
from generators.contact import fingertip_distance
from generators.hand import forward_kinematics
from generators.interception import HandPlan, plan_episode
from generators.visibility import first_hidden_frame
from schemas.errors import InfeasibleError
from schemas.events import palm_distance, spec_hover_offset
from schemas.frames import EpisodeFrames
from schemas.objects import object_category
from schemas.scene import MIN_OBSERVE_VISIBLE
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


def assemble_frames(
    spec: EpisodeSpec,
    phase: np.ndarray,
    object_pose: np.ndarray,
    object_velocity: np.ndarray,
    palm_pose: np.ndarray,
    joint_angles: np.ndarray,
    action: np.ndarray,
    grasp_angles: np.ndarray,
) -> EpisodeFrames:
    """Complete per-frame states with FK (joint poses, keypoints), the two distances and,
    with obstacles, the hand's clearance from them."""
    joint_poses, keypoints = forward_kinematics(palm_pose, joint_angles, spec.hand)
    n = len(phase)
    tips = keypoints.reshape(n, 6, 6)[:, :5, :3]
    f32 = np.float32
    return EpisodeFrames(
        phase=np.asarray(phase, dtype=np.int8),
        object_pose=np.asarray(object_pose, dtype=f32),
        object_velocity=np.asarray(object_velocity, dtype=f32),
        palm_pose=np.asarray(palm_pose, dtype=f32),
        joint_angles=np.asarray(joint_angles, dtype=f32),
        joint_poses=joint_poses.astype(f32),
        keypoints=keypoints.astype(f32),
        action=np.asarray(action, dtype=f32),
        fingertip_distance=fingertip_distance(tips, spec.object, spec.object_size, object_pose).astype(f32),
        palm_distance=palm_distance(palm_pose[:, :3], object_pose[:, :3], spec_hover_offset(spec)).astype(f32),
        grasp_angles=np.asarray(grasp_angles, dtype=f32),
        obstacle_clearance=obstacle_clearance(spec, palm_pose, joint_angles),
    )


def obstacle_clearance(spec: EpisodeSpec, palm_pose: np.ndarray, joint_angles: np.ndarray) -> np.ndarray | None:
    """(n,) float32 clearance of the hand from the spec's obstacles, computed from the states
    as recorded (float32), so a reader recomputing it from the shard gets the same values;
    None without obstacles."""
    if not spec.obstacles:
        return None
    palm = np.asarray(palm_pose, dtype=np.float32).astype(np.float64)
    joints = np.asarray(joint_angles, dtype=np.float32).astype(np.float64)
    return hand_clearance(palm, joints, spec.hand, spec.obstacles).astype(np.float32)


def check_observable(spec: EpisodeSpec, poses: np.ndarray) -> None:
    """Refuse an episode whose object is not shown enough (in the image and unhidden by the
    resting hand) in some observe frame: the protocol promises the model sees the motion."""
    hidden = first_hidden_frame(spec.object, spec.object_size, spec.hand, poses[: spec.observe_frames], spec.obstacles)
    if hidden is not None:
        frame, fraction = hidden
        raise InfeasibleError(
            f"the object is only {fraction:.0%} visible at observe frame {frame} (the resting hand, an "
            f"obstacle or the image edge hides the rest; at least {MIN_OBSERVE_VISIBLE:.0%} must show)"
        )


def plan(spec: EpisodeSpec) -> tuple[HandPlan, np.ndarray, np.ndarray]:
    """The ground-truth hand plan of ``spec`` with the object's poses and velocities.

    Raises :class:`InfeasibleError` when the object would be hidden while observed or the
    interception cannot be planned."""
    poses, velocity, sample = object_trajectory(spec)
    check_observable(spec, poses)
    lift = None
    if spec.motion.airborne:
        e = elevation(spec.motion, frame_times(spec.num_frames))
        lift = (e.height, e.velocity, e.acceleration)
    return plan_episode(spec, sample.position, sample.velocity, sample.acceleration, lift), poses, velocity


def episode(spec: EpisodeSpec) -> EpisodeFrames:
    """Ground-truth states and actions of every frame of ``spec`` (float32 arrays).

    Raises :class:`schemas.errors.InfeasibleError` when the interception cannot be planned.
    """
    hand, poses, velocity = plan(spec)
    return assemble_frames(
        spec, hand.phase, poses, velocity, hand.palm_pose, hand.joint_angles, hand.action, hand.grasp_angles
    )

