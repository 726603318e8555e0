"""Misbehaving policies for the fault tests, importable as ``tests.pipeline.faulty_policies:NAME``
(so that Dask workers and `pipeline eval` can resolve them).

Each behaves like ``still`` (repeat the current hand state) until its third ``act``
call, where it commits its fault.
"""

from __future__ import annotations

import json
import time

import numpy as np

from pipeline.policies.base import state_action

FAULT_CALL = 3
HANG_S = 3.0


def faulty_action(fault: str | None, obs: dict, calls: int):
    """The action of call number ``calls``: the still action, or the fault at FAULT_CALL."""
    action = state_action(obs)
    if fault is None or calls != FAULT_CALL:
        return action
    if fault == "nan":
        action[4] = np.nan
        return action
    if fault == "inf":
        chunk = np.stack([action, action])
        chunk[1, 0] = np.inf
        return chunk
    if fault == "shape":
        return action[:17]
    if fault == "raise":
        raise ValueError("the model diverged")
    if fault == "tensor":
        return Unconvertible()
    if fault == "complex":
        return action * (1 + 1j)
    if fault == "hang":
        time.sleep(HANG_S)
        return action
    raise AssertionError(fault)


class Unconvertible:
    """Like a tensor that refuses conversion (``requires_grad``, on a GPU): its
    ``__array__`` raises something other than TypeError/ValueError."""

    def __array__(self, dtype=None, copy=None):
        raise RuntimeError("Can't call numpy() on Tensor that requires grad")


class Single:
    """One fault in every episode (the class attribute ``fault``)."""

    name = "single-fault"
    action_horizon = 1
    privileged = False
    fault: str | None = None

    def reset(self, task: dict) -> None:
        self.calls = 0
        if self.fault == "reset":
            raise RuntimeError("cannot load the weights")

    def act(self, obs: dict):
        self.calls += 1
        return faulty_action(self.fault, obs, self.calls)


class ComplexFault(Single):
    fault = "complex"


class RaiseFault(Single):
    fault = "raise"


class Escapes(Single):
    """A hostile name and error text: terminal escapes and newlines."""

    name = "evil\x1b[2J\nname"

    def act(self, obs: dict):
        raise RuntimeError("\x1b[2J\x1b[31mclear\nscreen")


class Mixed:
    """Privileged (it reads the episode index from the spec): a different fault per episode."""

    name = "mixed-faults"
    action_horizon = 1
    privileged = True
    FAULTS = {1: "nan", 2: "inf", 3: "shape", 4: "raise", 5: "hang", 6: "reset"}

    def reset(self, task: dict) -> None:
        self.fault = self.FAULTS.get(json.loads(task["spec"])["episode_index"])
        self.calls = 0
        if self.fault == "reset":
            raise RuntimeError("cannot load the weights")

    def act(self, obs: dict):
        self.calls += 1
        return faulty_action(self.fault, obs, self.calls)


class Slow:
    """Answers correctly (stands still) but takes ``delay_s`` per call, for a few calls."""

    name = "slow"
    action_horizon = 1
    privileged = False
    delay_s = 0.25

    def reset(self, task: dict) -> None:
        self.calls = 0

    def act(self, obs: dict):
        self.calls += 1
        if self.calls <= 3:
            time.sleep(self.delay_s)
        return state_action(obs)


class Dying:
    """Takes its own process down in various ways, one per episode, counted across
    processes in ``$DYANA_TEST_COUNTER`` (a file): episode 1 prints 5 MB and succeeds,
    2 calls os._exit(3), 3 calls sys.exit(4), 4 raises KeyboardInterrupt, 5 succeeds."""

    name = "dying"
    action_horizon = 1
    privileged = False

    def reset(self, task: dict) -> None:
        import os

        path = os.environ["DYANA_TEST_COUNTER"]
        with open(path, "a") as handle:
            handle.write("x")
        with open(path) as handle:
            self.episode = len(handle.read())
        self.calls = 0

    def act(self, obs: dict):
        import os
        import sys

        self.calls += 1
        if self.calls == 2:
            if self.episode == 1:
                print("noise " * 900_000)
            elif self.episode == 2:
                os._exit(3)
            elif self.episode == 3:
                sys.exit(4)
            elif self.episode == 4:
                raise KeyboardInterrupt
        return state_action(obs)


class HugeReply(Single):
    """Answers with a 14 MB action chunk: over the 1 MiB a reply to Dyana's client may hold."""

    def act(self, obs: dict):
        import numpy as np

        return np.zeros((200_000, 18), np.float32)
