"""What every harder-setting episode draws first, and the redraw loop that follows.

Episode ``i`` of a slice draws from ``Generator(PCG64(SeedSequence([seed, i])))``: first
its choices, in this order: observe window, object (from the setting's pool), size
factor, hand, text template (:func:`common_choices`); the setting's own choices and its
motion attempts follow from the same generator. :func:`first_feasible` keeps the first
attempt the episode stage can plan.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from generators.bounds import motion_bounds
from generators.camera import in_view
from generators.grids import OBJECT_NAMES, SIZE_FACTORS
from generators.ground_truth import plan
from generators.visibility import rest_shadow_z
from schemas.errors import InfeasibleError
from schemas.motion import Motion
from schemas.scene import GRASP_FRAMES, HANDS, HOLD_FRAMES, INTERCEPT_SECONDS, WORKSPACE_X, WORKSPACE_Z
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

SETTINGS = tuple(INTERCEPT_SECONDS)


def uniform(rng: np.random.Generator, low: float, high: float) -> float:
    """One draw in ``[low, high)`` from 53 random bits (``Generator.random``)."""
    return low + (high - low) * float(rng.random())


def episode_rng(seed: int, index: int) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, index])))


@dataclass(frozen=True)
class CommonChoices:
    """An episode's draws before any motion is tried."""

    setting: str
    observe_frames: int
    num_frames: int
    object_index: int
    size_index: int
    hand: str
    text: int

    @property
    def object_name(self) -> str:
        return OBJECT_NAMES[self.object_index]


def common_choices(
    rng: np.random.Generator,
    setting: str,
    observe_seconds: tuple[float, float],
    objects: Sequence[int],
    texts: int,
) -> CommonChoices:
    """Observe window, object (an index into ``objects``), size, hand and text template."""
    observe = round(uniform(rng, *observe_seconds) * FPS)
    num_frames = observe + round(INTERCEPT_SECONDS[setting] * FPS) + GRASP_FRAMES + HOLD_FRAMES
    obj = objects[int(rng.random() * len(objects))]
    size_index = int(rng.random() * len(SIZE_FACTORS))
    hand = HANDS[int(rng.random() * len(HANDS))]
    text = int(rng.random() * texts)
    return CommonChoices(setting, observe, num_frames, obj, size_index, hand, text)


def path_fits(motion: Motion, seconds: float, radius: float, top: float | None = None) -> bool:
    """The object's horizontal path over ``[0, seconds]`` (footprint ``radius``) stays in the
    workspace and beyond the resting hand's shadow; with ``top``, its bounding box from the
    table to that height is in the camera's view too."""
    x0, x1, z0, z1 = motion_bounds(motion, seconds)
    if x0 < WORKSPACE_X[0] or x1 > WORKSPACE_X[1] or z0 < WORKSPACE_Z[0] or z1 > WORKSPACE_Z[1]:
        return False
    if z0 - radius <= rest_shadow_z():
        return False
    if top is None:
        return True
    xs, zs, ys = np.array([x0 - radius, x1 + radius]), np.array([z0 - radius, z1 + radius]), np.array([0.0, top])
    x, y, z = np.meshgrid(xs, ys, zs, indexing="ij")
    return bool(in_view(x.ravel(), y.ravel(), z.ravel()).all())


def first_feasible(attempt: Callable[[], EpisodeSpec | None], attempts: int, slice_name: str, index: int) -> EpisodeSpec:
    """The first spec ``attempt`` returns (None: it did not fit) whose ground truth
    plans (:func:`generators.ground_truth.plan`); InfeasibleError after ``attempts`` tries."""
    for _ in range(attempts):
        spec = attempt()
        if spec is None:
            continue
        try:
            plan(spec)
        except InfeasibleError:
            continue
        return spec
    raise InfeasibleError(f"episode {index} of {slice_name} found no feasible motion in {attempts} attempts")
