"""What a learner sees and issues: :class:`~pipeline.loop.env.DyanaEnv`'s ``obs`` and
``normalize_actions`` options.

``obs`` picks a view of the full observation (:class:`~pipeline.loop.spaces.Observation`):

* ``"full"`` (``DyanaEnv()``'s default and ``Dyana/GraspFull-v0``'s): the full dict, the
  policy contract ``pipeline eval`` uses;
* ``"image"``: the (H, W, 3) uint8 frame alone (Stable-Baselines3's ``CnnPolicy``);
* ``"state"``: :data:`STATE_WIDTH` float32 numbers, the hand's state and the time:
  ``palm_pose`` (6), ``joint_angles`` (15), ``joint_poses`` (90), ``keypoints`` (36),
  then ``timestamp`` (1), bounded as in the full space (``MlpPolicy``). The object is
  only in the image: this view is proprioception, no privileged state;
* ``"both"``: ``{"image": ..., "state": ...}`` (``MultiInputPolicy``), with
  ``normalize_actions=True`` what a plain ``gymnasium.make("Dyana/Grasp-v0")`` gives.

Every view is a fixed-shape Box or a Dict of Boxes, so vector environments batch it
into shared memory and any learning library takes it as it is. ``normalize_actions``
makes the action space the Box [-1, 1]^18, mapped linearly onto the real one
(:func:`pipeline.loop.spaces.action_space`): -1 is the lower bound, 1 the upper; values
beyond are clipped, as the real action is.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from gymnasium import spaces

from pipeline.loop.actions import as_action
from pipeline.loop.spaces import ACTION_WIDTH, Observation, action_space, observation_space

#: The full observation's keys the ``state`` view concatenates, in order (then the timestamp).
STATE_KEYS = ("palm_pose", "joint_angles", "joint_poses", "keypoints")
STATE_WIDTH = 6 + 15 + 90 + 36 + 1


def state_space(resolution: int) -> spaces.Box:
    """The ``state`` view's float32 Box, its bounds those of the full space's keys."""
    full = observation_space(resolution)
    boxes = [cast(spaces.Box, full[k]) for k in (*STATE_KEYS, "timestamp")]
    low = np.concatenate([np.atleast_1d(b.low) for b in boxes])
    high = np.concatenate([np.atleast_1d(b.high) for b in boxes])
    return spaces.Box(low.astype(np.float32), high.astype(np.float32), (STATE_WIDTH,), np.float32)


def state_vector(obs: Observation) -> np.ndarray:
    """The ``state`` view of one full observation."""
    values: dict[str, Any] = dict(obs)
    parts = [np.asarray(values[k], dtype=np.float32) for k in STATE_KEYS]
    return np.concatenate([*parts, np.asarray(obs["timestamp"], dtype=np.float32).reshape(1)])


def image_space(resolution: int) -> spaces.Box:
    return spaces.Box(0, 255, (resolution, resolution, 3), np.uint8)


@dataclass(frozen=True)
class ObservationView:
    """One ``obs`` option: its space at a resolution and the observation it shows."""

    space: Callable[[int], spaces.Space[Any]]
    show: Callable[[Observation], Any]


VIEWS: dict[str, ObservationView] = {
    "full": ObservationView(observation_space, lambda obs: obs),
    "image": ObservationView(image_space, lambda obs: obs["image"]),
    "state": ObservationView(state_space, state_vector),
    "both": ObservationView(
        lambda res: spaces.Dict({"image": image_space(res), "state": state_space(res)}),
        lambda obs: {"image": obs["image"], "state": state_vector(obs)},
    ),
}


def normalized_action_space() -> spaces.Box:
    """The Box [-1, 1]^18 of ``normalize_actions=True``."""
    return spaces.Box(-1.0, 1.0, (ACTION_WIDTH,), np.float32)


def absolute_action(action: object) -> np.ndarray:
    """A normalised action as the real one (float32 (18,)): clipped to [-1, 1], then
    mapped linearly onto the action Box. A wrong shape or NaN/inf: PolicyError."""
    act = np.clip(as_action(action).astype(np.float64), -1.0, 1.0)
    real = action_space()
    low, high = real.low.astype(np.float64), real.high.astype(np.float64)
    return (low + (act + 1.0) / 2.0 * (high - low)).astype(np.float32)
