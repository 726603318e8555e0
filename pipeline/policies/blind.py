"""Blind reference policies: what a benchmark score is worth without looking.

Each plays a fixed plan that never depends on where the object is, except
``blind-first-seen``, which reads one frame (the first of the observe window) once.
They read the task's public conditions (the instruction's object category, the
interception setting's time, the observe window's length, the frame rate) and the
hand's own state (``palm_pose``, ``frame_index``); never ``image`` (``blind-first-seen``:
only ``observe_images[0]``, in its first call). Their scores are chance levels: a
metric a blind policy reaches does not show that a model sees (``scoring eval
--chance RUN ...``).

All four hover the palm at the named object's nominal top plus the grasp design's
hover height (:func:`~pipeline.policies.grip.hover_over_top`), move it at most :data:`MAX_STEP` per frame toward
their target, and start closing the hand fully (minimum jerk over ``GRASP_FRAMES``
frames, to the end of each finger's synergy: :data:`~pipeline.policies.grip.FIST`) at the interception time, when the
ground truth arrives, so they all "grasp" (S_gra) whatever they touch:

=====================  =================================================================
``blind-centre``       waits over the workspace centre :data:`CENTRE`
``blind-sweep``        runs back and forth along the fixed raster :data:`SWEEP` over the
                       workspace at :data:`SWEEP_SPEED` per frame
``blind-first-seen``   goes over where the object is in the first observe frame, waits
``blind-fitted``       follows the mean ground-truth palm path of the training slices for
                       its interception setting (``blind_path.json``, made by
                       :mod:`pipeline.policies.blind_fit` from training episodes only),
                       closing at their median closing frame
=====================  =================================================================

Pure and deterministic: an action depends on the task and the observations given only.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from generators.hand import REST_JOINTS
from pipeline.policies.base import DEFAULT_INTERCEPT_TIME_S, Observation, Task
from pipeline.policies.grip import FIST, closing_joints, hover_over_top
from pipeline.policies.perception import ObjectLocator, object_from_text
from schemas.errors import PolicyError
from schemas.objects import OBJECTS
from schemas.scene import INTERCEPT_SECONDS, PALM_REST, WORKSPACE_X, WORKSPACE_Z

#: Longest palm step per frame (units): the fitted path is followed at most this fast.
MAX_STEP = 1.0
#: The workspace's centre (x, z).
CENTRE = ((WORKSPACE_X[0] + WORKSPACE_X[1]) / 2, (WORKSPACE_Z[0] + WORKSPACE_Z[1]) / 2)
#: The sweep's waypoints (x, z): three rows across the workspace, boustrophedon.
SWEEP = ((-3.0, 2.5), (3.0, 2.5), (3.0, 4.5), (-3.0, 4.5), (-3.0, 6.5), (3.0, 6.5))
#: The sweep's speed along its waypoints (units per frame; 5 units/s).
SWEEP_SPEED = 0.25
#: Hover height when the instruction names no known object (the rest height).
DEFAULT_HOVER_Y = PALM_REST[1]
#: The fitted paths (:mod:`pipeline.policies.blind_fit` writes them).
PATH_FILE = Path(__file__).with_name("blind_path.json")


def hover_height(text: str, hand: str = "right") -> float:
    """The palm height over the instruction's object at its nominal size (top + the
    design's hover for ``hand``, :func:`~pipeline.policies.grip.hover_over_top`)."""
    name = object_from_text(text)
    if name is None:
        return DEFAULT_HOVER_Y
    category = OBJECTS[name]
    return 2.0 * category.half_height(category.nominal_size) + hover_over_top(name, category.nominal_size, hand)


def setting_of(intercept_time_s: float) -> str:
    """The interception setting whose time is closest to ``intercept_time_s``."""
    return min(INTERCEPT_SECONDS, key=lambda name: abs(INTERCEPT_SECONDS[name] - intercept_time_s))


def along(points: np.ndarray, distance: float) -> np.ndarray:
    """The point ``distance`` along the polyline ``points`` (k, d), running back and forth."""
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    total = float(lengths.sum())
    s = distance % (2.0 * total)
    if s > total:
        s = 2.0 * total - s
    ends = np.cumsum(lengths)
    k = min(int(np.searchsorted(ends, s)), len(lengths) - 1)
    start = ends[k] - lengths[k]
    fraction = 0.0 if lengths[k] == 0 else (s - start) / lengths[k]
    return points[k] + fraction * (points[k + 1] - points[k])


class BlindPolicy:
    """The shared loop (module docstring): subclasses say where the palm goes (:meth:`target`)."""

    name = "blind"
    action_horizon = 1
    privileged = False

    def __init__(self) -> None:
        self._first: int | None = None

    def reset(self, task: Task) -> None:
        fps = int(task["fps"])
        self._first = int(task["observe_frames"])
        self._hover = hover_height(str(task["text"]), str(task["hand"]))
        self._intercept_s = float(task.get("intercept_time_s", DEFAULT_INTERCEPT_TIME_S))
        self._close_at = self._first + self.close_frame(round(self._intercept_s * fps))
        self._text = str(task["text"])
        self._resolution = int(task["resolution"])

    def close_frame(self, intercept_frames: int) -> int:
        """Acting frames from the first to the start of closing (default: the interception time)."""
        return intercept_frames

    def target(self, t: int, obs: Observation) -> np.ndarray:
        """The palm's goal (x, y, z) at acting frame ``t``."""
        raise NotImplementedError

    def act(self, obs: Observation) -> np.ndarray:
        if self._first is None:
            raise PolicyError("act() before reset()")
        k = int(obs["frame_index"])
        palm = np.asarray(obs["palm_pose"], dtype=np.float64)[:3]
        step = self.target(k - self._first, obs) - palm
        length = float(np.linalg.norm(step))
        if length > MAX_STEP:
            step *= MAX_STEP / length
        joints = REST_JOINTS if k + 1 < self._close_at else closing_joints(FIST, k + 1 - self._close_at)
        return np.concatenate([palm + step, joints]).astype(np.float32)


class CentrePolicy(BlindPolicy):
    """``blind-centre``: hovers over the workspace centre and waits."""

    name = "blind-centre"

    def target(self, t: int, obs: Observation) -> np.ndarray:
        return np.array([CENTRE[0], self._hover, CENTRE[1]])


class SweepPolicy(BlindPolicy):
    """``blind-sweep``: back and forth along the fixed raster :data:`SWEEP`."""

    name = "blind-sweep"

    def target(self, t: int, obs: Observation) -> np.ndarray:
        x, z = along(np.asarray(SWEEP, dtype=np.float64), SWEEP_SPEED * max(t, 0))
        return np.array([x, self._hover, z])


class FirstSeenPolicy(BlindPolicy):
    """``blind-first-seen``: over where the object is in the first frame it is shown
    (the observe window's first, or the first acting frame without a window), then waits.
    Reads that one frame once; the table centre if the object is not found in it."""

    name = "blind-first-seen"

    def reset(self, task: Task) -> None:
        super().reset(task)
        self._goal: np.ndarray | None = None

    def target(self, t: int, obs: Observation) -> np.ndarray:
        if self._goal is None:
            window = obs["observe_images"]
            frame = window[0] if len(window) else obs["image"]
            locator = ObjectLocator(self._text, self._resolution)
            # the observe window shows the resting hand, as the first acting frame does
            seen = locator.locate(frame, obs["palm_pose"], obs["joint_poses"], obs["keypoints"])
            x, z = CENTRE if seen is None else (float(seen.position[0]), float(seen.position[2]))
            self._goal = np.array([x, self._hover, z])
        return self._goal


@lru_cache(maxsize=1)
def fitted_paths() -> dict[str, tuple[np.ndarray, int]]:
    """Per interception setting: the fitted palm path (frames, 3) and the closing frame."""
    try:
        data = json.loads(PATH_FILE.read_text())
        return {
            setting: (np.asarray(entry["palm"], dtype=np.float64), int(entry["close_frame"]))
            for setting, entry in data["paths"].items()
        }
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise PolicyError(f"{PATH_FILE.name}: cannot read the fitted paths ({exc})") from None


class FittedPolicy(BlindPolicy):
    """``blind-fitted``: the mean training path of its interception setting, at most
    :data:`MAX_STEP` per frame, closing at the training episodes' median closing frame.
    Its height is the path's (the training objects' mean hover height)."""

    name = "blind-fitted"

    def reset(self, task: Task) -> None:
        self._path, self._close = fitted_paths()[setting_of(float(task.get("intercept_time_s", DEFAULT_INTERCEPT_TIME_S)))]
        super().reset(task)

    def close_frame(self, intercept_frames: int) -> int:
        return self._close

    def target(self, t: int, obs: Observation) -> np.ndarray:
        return self._path[min(max(t, 0), len(self._path) - 1)]
