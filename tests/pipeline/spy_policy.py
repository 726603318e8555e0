"""A policy that writes down everything it is given (a test helper), importable as
``tests.pipeline.spy_policy:SpyPolicy`` (so `pipeline serve` can run it): each task and
each observation, arrays as their shape and dtype, one JSON object per line, appended to
the file named by the environment variable :data:`OUT_ENV`."""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from pipeline.policies.base import Observation, Task, state_action

OUT_ENV = "DYANA_SPY_OUT"


def plain(value: Any) -> Any:
    """``value`` as JSON: arrays as ``{"shape", "dtype"}`` (0-d ones as their number)."""
    if isinstance(value, np.ndarray):
        return value.item() if value.ndim == 0 else {"shape": list(value.shape), "dtype": str(value.dtype)}
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


class SpyPolicy:
    name = "spy"
    action_horizon = 1
    privileged = False

    def _write(self, kind: str, value: Any) -> None:
        with open(os.environ[OUT_ENV], "a") as handle:
            handle.write(json.dumps({"kind": kind, "value": plain(value)}, sort_keys=True) + "\n")

    def reset(self, task: Task) -> None:
        self._write("task", task)

    def act(self, obs: Observation) -> np.ndarray:
        self._write("observation", obs)
        return state_action(obs)
