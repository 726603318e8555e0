"""The ground-truth plan of an episode: the object's trajectory at the frame times, the
observability check of the observe window and the hand's interception plan.

The slice generators call :func:`plan` to keep only interceptable episodes; the episode
stage (:mod:`pipeline.stages.episode`) turns the plan into the recorded frames.
"""

from __future__ import annotations

import numpy as np

from generators import motion
from generators.ballistics import elevation
from generators.interception import HandPlan, plan_episode
from generators.visibility import first_hidden_frame
from schemas.errors import InfeasibleError
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
