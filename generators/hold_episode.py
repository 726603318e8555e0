"""The hold test of a whole episode: find the frame the grasp closes, take the hand's and the
(scripted) object's state there, and run :func:`generators.hold.hold_test`.

What the closed loop and the scorer call: an episode's spec and the hand it recorded
(palm poses and joint angles per frame) are enough, since the object follows its
scripted motion (:mod:`generators.motion`) until the grasp closes.
"""

from __future__ import annotations

import numpy as np

from generators import motion
from generators.grasp import DEFAULT_DESIGN, GraspDesign
from generators.ground_truth import episode_grasp
from generators.hold import HoldResult, hold_test
from schemas.errors import SpecError
from schemas.events import grasp_closed
from schemas.spec import EpisodeSpec
from schemas.versions import FPS


def closing_frame(joint_angles: np.ndarray, grasp: np.ndarray) -> int | None:
    """The first frame whose joints reach the grasp criterion (:func:`schemas.events.grasp_closed`), or None."""
    closed = grasp_closed(joint_angles, grasp)
    return int(np.argmax(closed)) if closed.any() else None


def palm_velocity(palm_pose: np.ndarray, frame: int) -> np.ndarray:
    """(3,) the palm's velocity at ``frame`` (units/s): its last step times FPS (0 at frame 0),
    what a controller that sees frames knows."""
    if frame == 0:
        return np.zeros(3)
    return (palm_pose[frame, :3] - palm_pose[frame - 1, :3]) * float(FPS)


def episode_hold(spec: EpisodeSpec, palm_pose: np.ndarray, joint_angles: np.ndarray,
                 design: GraspDesign = DEFAULT_DESIGN) -> tuple[int, HoldResult] | None:
    """The closing frame and the hold test's result of an episode whose hand went through
    ``palm_pose`` (n, 6) and ``joint_angles`` (n, 15) (frames 0..n-1 of ``spec``; a rollout may run past
    ``num_frames``, where the motion's closed form extrapolates); None when
    the grasp never closes (nothing to hold). ``design``: the hand, and the ground truth's
    grasp the closing criterion compares with (:func:`generators.ground_truth.episode_grasp`)."""
    palm = np.asarray(palm_pose, dtype=np.float64)
    joints = np.asarray(joint_angles, dtype=np.float64)
    n = palm.shape[0] if palm.ndim == 2 else -1
    if n < 1 or palm.shape != (n, 6) or joints.shape != (n, 15) or not (np.isfinite(palm).all() and np.isfinite(joints).all()):
        raise SpecError(f"episode hold: need finite palm_pose (n, 6) and joint_angles (n, 15), n >= 1, "
                        f"got {palm.shape} and {joints.shape}")
    frame = closing_frame(joints, episode_grasp(spec, design))
    if frame is None:
        return None
    return frame, hold_at(spec, frame, palm[frame], palm_velocity(palm, frame), joints[frame], design)


def hold_at(spec: EpisodeSpec, frame: int, palm_pose: np.ndarray, palm_vel: np.ndarray,
            joint_angles: np.ndarray, design: GraspDesign = DEFAULT_DESIGN) -> HoldResult:
    """The hold test of ``spec`` from ``frame`` (where its grasp closed), the hand there at
    ``palm_pose`` (6,) moving at ``palm_vel`` (3,), units/s, with ``joint_angles`` (15,), the
    object in its scripted state at that frame's time."""
    t = np.array([frame / float(FPS)])
    pose, velocity = motion.object_pose(spec.motion, spec.object, spec.object_size, t)
    spin = motion.object_angular_velocity(spec.motion, spec.object, spec.object_size, t)
    return hold_test(spec.object, spec.object_size, spec.hand, palm_pose, palm_vel, joint_angles,
                     pose[0], velocity[0], spin[0], design.hand)
