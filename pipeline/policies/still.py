"""``still``: never moves. The hand stays where it is, fingers open: the lower bound."""

from __future__ import annotations

import numpy as np

from pipeline.policies.base import Observation, Task, state_action


class StillPolicy:
    """Every action repeats the current hand state."""

    name = "still"
    action_horizon = 1
    privileged = False

    def reset(self, task: Task) -> None:
        return None

    def act(self, obs: Observation) -> np.ndarray:
        return state_action(obs)
