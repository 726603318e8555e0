"""``oracle``: the ground-truth plan, the upper bound. Privileged: its task carries the
spec, from which it plans the episode exactly as the build does
(:func:`pipeline.stages.episode.episode`) and replays the plan's actions by frame index, so
through the environment it reproduces the ground truth's states."""

from __future__ import annotations

import numpy as np

from pipeline.policies.base import Observation, Task
from pipeline.stages.episode import episode
from schemas.errors import PolicyError
from schemas.spec import EpisodeSpec


class OraclePolicy:
    """Plays ``episode(spec).action[frame_index]``; past the plan's end, holds its last state."""

    name = "oracle"
    action_horizon = 1
    privileged = True

    def __init__(self) -> None:
        self._actions: np.ndarray | None = None

    def reset(self, task: Task) -> None:
        if "spec" not in task:
            raise PolicyError("the oracle needs the spec in its task (it is privileged)")
        self._actions = episode(EpisodeSpec.from_json(task["spec"])).action

    def act(self, obs: Observation) -> np.ndarray:
        if self._actions is None:
            raise PolicyError("act() before reset()")
        k = min(int(obs["frame_index"]), len(self._actions) - 1)
        return self._actions[k].copy()
