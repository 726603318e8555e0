"""The paper's harder settings (A.11) as slices: who makes each episode, and a slice's
stats from its episodes' choices alone.

Each setting's module (:mod:`generators.projectile`, :mod:`generators.obstacles`,
:mod:`generators.irregular`) makes episode ``i`` of a slice from
``SeedSequence([seed, i])``, its choices first (so frames and objects are known without
trying a motion). ``test-complex`` interleaves the three settings: episode ``i`` is
setting ``SETTINGS[i % 3]``, and within it the interception setting (and the irregular
family) cycle with ``i // 3``, so any prefix of the set covers all three settings.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module

import numpy as np

from schemas.objects import OBJECTS
from schemas.slices import SliceDef
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

#: The harder settings in ``test-complex`` order, with the module that makes each.
SETTINGS = ("projectile", "obstacle", "irregular")
_MODULES = {"projectile": "generators.projectile", "obstacle": "generators.obstacles", "irregular": "generators.irregular"}
_SPEC_FUNCTIONS = {"projectile": "projectile_spec", "obstacle": "obstacle_spec", "irregular": "irregular_spec"}


def _module(setting: str):
    return import_module(_MODULES[setting])


def _place(definition: SliceDef, index: int) -> tuple[str, int | None]:
    """(setting, cycle) of episode ``index``: a mixed set interleaves the settings."""
    if definition.generator == "complex":
        return SETTINGS[index % len(SETTINGS)], index // len(SETTINGS)
    return definition.generator, None


def appendix_spec(definition: SliceDef, index: int) -> EpisodeSpec:
    """Episode ``index`` of a harder-setting slice."""
    setting, cycle = _place(definition, index)
    make: Callable[..., EpisodeSpec] = getattr(_module(setting), _SPEC_FUNCTIONS[setting])
    return make(definition.name, definition.seed, definition.intercept_setting, index, cycle)


def appendix_summary(definition: SliceDef, episodes: int) -> dict:
    """``catalog stats`` of a harder-setting slice from its choices alone: every episode's
    motion is its own parameter set."""
    frames: dict[str, list[int]] = {s: [] for s in SETTINGS}
    objects: set[str] = set()
    for index in range(episodes):
        setting, cycle = _place(definition, index)
        chosen, _ = _module(setting).choices(definition.seed, index, definition.intercept_setting, cycle)
        common = getattr(chosen, "common", chosen)
        frames[setting].append(common.num_frames)
        objects.add(common.object_name)
    total = int(sum(sum(f) for f in frames.values()))
    return {
        "slice": definition.name,
        "total_episodes": episodes,
        "total_frames": total,
        "total_seconds": round(total / FPS, 2),
        "objects": {"categories": len(objects), "rolling": sum(1 for o in objects if OBJECTS[o].rolling)},
        "rollout_formats": {"observe-before-act": episodes, "direct-act": 0},
        "motion_types": {
            setting: {
                "episodes": len(f),
                "parameter_sets": len(f),
                "mean_frames": round(float(np.mean(f)), 2),
            }
            for setting, f in frames.items()
            if f
        },
    }
