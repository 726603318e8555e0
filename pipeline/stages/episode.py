"""The episode stage: ``EpisodeSpec`` -> per-frame states and actions, no rendering.

``episode(spec)`` takes the ground-truth plan (:func:`generators.ground_truth.plan`:
the object's motion at the frame times ``k / FPS`` and the interception), runs the
hand's forward kinematics and measures the events (palm XZ distance to the object's
centre, fingertip distance to its surface): :func:`assemble_frames`. The build records
its output; the closed loop's recorder (:class:`pipeline.loop.wrappers.RecordEpisode`)
turns the states its policy produced into the same arrays with the same function.

``pipeline.episode(spec)`` is this module's :func:`episode`, loaded on first call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from generators.clearance import hand_clearance
from generators.contact import fingertip_distance
from generators.ground_truth import plan
from generators.hand import forward_kinematics
from schemas.errors import SpecError
from schemas.events import palm_distance, spec_hover_offset
from schemas.frames import EpisodeFrames
from schemas.names import shorten
from schemas.spec import EpisodeSpec


@dataclass(frozen=True)
class HandMeasures:
    """What the hand's states imply, per frame (float32): forward kinematics and the two
    event distances."""

    #: (n, 90) the 15 joint frames.
    joint_poses: np.ndarray
    #: (n, 36) the 5 fingertips and the wrist.
    keypoints: np.ndarray
    #: (n,) the closest fingertip's distance to the object's surface.
    fingertip_distance: np.ndarray
    #: (n,) the localization distance (:func:`schemas.events.palm_distance`).
    palm_distance: np.ndarray


def measure_hand(
    spec: EpisodeSpec,
    palm_pose: np.ndarray,
    joint_angles: np.ndarray,
    object_pose: np.ndarray,
    kinematics: tuple[np.ndarray, np.ndarray] | None = None,
) -> HandMeasures:
    """Forward kinematics and distances of ``n`` frames, computed in float64 from the
    states as given (the ground truth's float64 plan, the environment's float32 states)
    and kept as float32. ``kinematics``: ``forward_kinematics(palm_pose, joint_angles,
    spec.hand)`` when the caller already has it (the closed loop, while the hand keeps
    its state); it is not recomputed."""
    if kinematics is None:
        kinematics = forward_kinematics(palm_pose, joint_angles, spec.hand)
    joint_poses, keypoints = kinematics
    n = len(joint_poses)
    tips = keypoints.reshape(n, 6, 6)[:, :5, :3]
    obj = np.asarray(object_pose, dtype=np.float64)
    f32 = np.float32
    return HandMeasures(
        joint_poses=joint_poses.astype(f32),
        keypoints=keypoints.astype(f32),
        fingertip_distance=fingertip_distance(tips, spec.object, spec.object_size, obj).astype(f32),
        palm_distance=palm_distance(np.asarray(palm_pose)[:, :3], obj[:, :3], spec_hover_offset(spec)).astype(f32),
    )


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
    """The recorded frames of an episode from its states: :func:`measure_hand` of every
    frame and, with obstacles, the hand's clearance from them. The ground truth passes its
    float64 plan, the closed loop's recorder the float32 states the environment reached."""
    measures = measure_hand(spec, palm_pose, joint_angles, object_pose)
    f32 = np.float32
    return EpisodeFrames(
        phase=np.asarray(phase, dtype=np.int8),
        object_pose=np.asarray(object_pose, dtype=f32),
        object_velocity=np.asarray(object_velocity, dtype=f32),
        palm_pose=np.asarray(palm_pose, dtype=f32),
        joint_angles=np.asarray(joint_angles, dtype=f32),
        joint_poses=measures.joint_poses,
        keypoints=measures.keypoints,
        action=np.asarray(action, dtype=f32),
        fingertip_distance=measures.fingertip_distance,
        palm_distance=measures.palm_distance,
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


def episode(spec: EpisodeSpec) -> EpisodeFrames:
    """Ground-truth states and actions of every frame of ``spec`` (float32 arrays).

    Raises :class:`schemas.errors.InfeasibleError` when the interception cannot be planned,
    and SpecError naming the argument when ``spec`` is not an EpisodeSpec.
    """
    if not isinstance(spec, EpisodeSpec):
        raise SpecError(f"spec must be a schemas.spec.EpisodeSpec, got {shorten(spec)} ({type(spec).__name__})")
    hand, poses, velocity = plan(spec)
    return assemble_frames(
        spec, hand.phase, poses, velocity, hand.palm_pose, hand.joint_angles, hand.action, hand.grasp_angles
    )

