"""``predictive``: the classical baseline. It localises the object from pixels, fits
a motion model, predicts where the object will be at the interception time, plans
a smooth approach there and closes the hand.

* **Observe.** In observe-before-act, every frame of the observe window is localised
  (:mod:`.perception`; the hand is at rest, as the first observation shows). In
  direct-act there is no window: the policy starts toward a staging point above the
  latest sighting while it collects the first samples from the acting frames.
* **Fit.** The sightings that show most of the object (:func:`reliable`) are fitted
  with line, arc and harmonic models (:mod:`.fitting`), the best by BIC; when the
  task text names the motion ("straight line", "circle", "back and forth") only that
  family is fitted (``PredictivePolicy(text_hint=False)`` always picks by residual).
  The fit is redone every frame a new reliable sighting arrives.
* **Plan.** The interception frame is ``observe_frames + round(intercept_time_s x
  fps)``, the public interception setting of the task. Each frame the palm's path is
  re-planned as a quintic from its current position, velocity and acceleration to
  the hover point over the predicted position (estimated object top plus
  :func:`~pipeline.policies.grip.hover_over_top`), arriving with the predicted velocity and
  acceleration, so the path stays smooth as the prediction improves.
* **Grasp.** From the interception frame the palm follows the prediction and the
  fingers close over ``GRASP_FRAMES`` frames (minimum jerk) to the grasp of the object
  it saw (:mod:`.grip`), as the ground truth does.

Deterministic; numpy only; a step costs a few milliseconds (perception and fit).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from generators.hand import REST_JOINTS
from pipeline.policies.base import DEFAULT_INTERCEPT_TIME_S, Observation, Task
from pipeline.policies.fitting import KINDS, MIN_SAMPLES, MotionFit, fit_motion
from pipeline.policies.grip import closing_joints, grip_angles, hover_over_top
from pipeline.policies.perception import Detection, ObjectLocator
from schemas.errors import PolicyError
from schemas.scene import WORKSPACE_X, WORKSPACE_Z

#: A sighting is fitted when it shows this share of the object, and matches its
#: silhouette this well (mismatched pixels over the silhouette's area).
MIN_COVERAGE = 0.4
MAX_MISMATCH = 0.6
#: Samples needed before the first fit.
MIN_FIT_SAMPLES = 4
#: Before any fit the palm heads for a staging point this high above the hover point
#: over the latest sighting showing at least STAGING_COVERAGE of the object.
STAGING_LIFT = 1.0
STAGING_COVERAGE = 0.3
#: The text phrases that name a motion family.
MOTION_WORDS = (
    ("line", re.compile(r"straight|\bline\b|linear")),
    ("arc", re.compile(r"circle|circular|\barc\b|orbit")),
    ("harmonic", re.compile(r"back and forth|swing|oscillat|harmonic|pendul")),
)


def motion_hint(text: str) -> tuple[str, ...]:
    """The model families to fit for a task text: the one it names, else all."""
    lowered = str(text).lower()
    named = tuple(kind for kind, pattern in MOTION_WORDS if pattern.search(lowered))
    return named if len(named) == 1 else KINDS


def reliable(seen: Detection | None) -> bool:
    """Whether a sighting is good enough to fit: most of the object in view."""
    return seen is not None and seen.coverage >= MIN_COVERAGE and seen.mismatch <= MAX_MISMATCH


@dataclass(frozen=True)
class Quintic:
    """A quintic path from ``t0`` to ``t1`` (seconds): coefficients (6, 3) in ``t - t0``."""

    t0: float
    t1: float
    coef: np.ndarray

    @classmethod
    def between(cls, t0: float, t1: float, start: tuple[np.ndarray, ...], end: tuple[np.ndarray, ...]) -> Quintic:
        """Position, velocity and acceleration ``start`` at ``t0`` and ``end`` at ``t1``."""
        (p0, v0, a0), (p1, v1, a1) = start, end
        T = t1 - t0
        h = p1 - p0
        c3 = (20 * h - (8 * v1 + 12 * v0) * T - (3 * a0 - a1) * T**2) / (2 * T**3)
        c4 = (-30 * h + (14 * v1 + 16 * v0) * T + (3 * a0 - 2 * a1) * T**2) / (2 * T**4)
        c5 = (12 * h - 6 * (v1 + v0) * T + (a1 - a0) * T**2) / (2 * T**5)
        return cls(t0, t1, np.stack([p0, v0, a0 / 2.0, c3, c4, c5]))

    def at(self, t: float, order: int = 0) -> np.ndarray:
        tau = float(np.clip(t, self.t0, self.t1)) - self.t0
        powers = np.array([tau**k for k in range(6)])
        if order == 0:
            weights = powers
        elif order == 1:
            weights = np.array([0.0] + [k * powers[k - 1] for k in range(1, 6)])
        else:
            weights = np.array([0.0, 0.0] + [k * (k - 1) * powers[k - 2] for k in range(2, 6)])
        return weights @ self.coef


class PredictivePolicy:
    """Observe, fit, predict, plan, grasp (module docstring)."""

    name = "predictive"
    action_horizon = 1
    privileged = False

    def __init__(self, text_hint: bool = True) -> None:
        self.text_hint = bool(text_hint)
        self._locator: ObjectLocator | None = None

    def reset(self, task: Task) -> None:
        self._fps = float(task["fps"])
        self._locator = ObjectLocator(str(task["text"]), int(task["resolution"]))
        self._hand = str(task["hand"])
        self._kinds = motion_hint(task["text"]) if self.text_hint else KINDS
        seconds = float(task.get("intercept_time_s", DEFAULT_INTERCEPT_TIME_S))
        self._intercept = int(task["observe_frames"]) + int(round(seconds * self._fps))
        self._times: list[float] = []
        self._points: list[np.ndarray] = []
        self._latest: np.ndarray | None = None
        self._fit: MotionFit | None = None
        self._plan: Quintic | None = None
        self._grip: np.ndarray | None = None
        self._started = False

    # sensing -------------------------------------------------------------------
    @property
    def locator(self) -> ObjectLocator:
        if self._locator is None:
            raise PolicyError("act() before reset()")
        return self._locator

    def _sight(self, image: np.ndarray, obs: Observation, t: float) -> bool:
        seen = self.locator.locate(image, obs["palm_pose"], obs["joint_poses"], obs["keypoints"])
        if seen is not None and seen.coverage >= STAGING_COVERAGE:
            self._latest = seen.position[[0, 2]]
        if seen is not None and reliable(seen):
            self._times.append(t)
            self._points.append(seen.position[[0, 2]])
            return True
        return False

    def _refit(self) -> None:
        enough = max(MIN_FIT_SAMPLES, min(MIN_SAMPLES[k] for k in self._kinds))
        if len(self._times) < enough:
            return
        kinds = tuple(k for k in self._kinds if len(self._times) >= MIN_SAMPLES[k])
        fit = fit_motion(np.array(self._times), np.array(self._points), kinds)
        if fit is not None:
            self._fit = fit

    def _hover(self, xz: np.ndarray) -> np.ndarray:
        category = self.locator.category.name if self.locator.category else None
        hover = hover_over_top(category, self.locator.size, self._hand)
        return np.array([xz[0], self.locator.top_height + hover, xz[1]])

    # acting ------------------------------------------------------------------
    def act(self, obs: Observation) -> np.ndarray:
        if self._locator is None:
            raise PolicyError("act() before reset()")
        k = int(obs["frame_index"])
        fresh = False
        if not self._started:
            self._started = True
            # the observe window's frames 0 .. K-1, the hand at rest as it is now
            window = obs.get("observe_images")
            for j, image in enumerate(window if window is not None else ()):
                fresh |= self._sight(image, obs, j / self._fps)
        fresh |= self._sight(obs["image"], obs, k / self._fps)
        if fresh:
            self._refit()

        palm = np.asarray(obs["palm_pose"], dtype=np.float64)[:3]
        t, t_next = k / self._fps, (k + 1) / self._fps
        t_arrive = self._intercept / self._fps
        if k + 1 <= self._intercept:
            goal = self._goal(t_arrive)
            if self._plan is not None and self._plan.t0 <= t <= self._plan.t1:
                start = (palm, self._plan.at(t, 1), self._plan.at(t, 2))
            else:
                start = (palm, np.zeros(3), np.zeros(3))
            self._plan = Quintic.between(t, t_arrive, start, goal)
            target = self._plan.at(t_next)
            joints = REST_JOINTS
        else:
            target = self._goal(t_next)[0]
            if self._grip is None:
                category = self._locator.category.name if self._locator.category else None
                self._grip = grip_angles(category, self._locator.size, self._hand)
            joints = closing_joints(self._grip, k + 1 - self._intercept)
        return np.concatenate([target, joints]).astype(np.float32)

    def _goal(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Hover point, velocity and acceleration of the predicted object at time ``t``."""
        if self._fit is not None:
            xz = self._fit.position(t)[0]
            xz = np.clip(xz, [WORKSPACE_X[0], WORKSPACE_Z[0]], [WORKSPACE_X[1], WORKSPACE_Z[1]])
            v, a = self._fit.velocity(t)[0], self._fit.acceleration(t)[0]
            return self._hover(xz), np.array([v[0], 0.0, v[1]]), np.array([a[0], 0.0, a[1]])
        seen = self._latest if self._latest is not None else np.array([0.0, sum(WORKSPACE_Z) / 2.0])
        staging = self._hover(seen) + np.array([0.0, STAGING_LIFT, 0.0])
        return staging, np.zeros(3), np.zeros(3)
