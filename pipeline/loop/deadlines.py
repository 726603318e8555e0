"""How long a policy call may take: the watchdog and the check of a number of seconds.

Apart from the rollout so that a job spec can check ``--deadline`` without importing the
closed loop (gymnasium, the environment): ``pipeline build`` never runs a policy.
"""

from __future__ import annotations

import math

from schemas.errors import PolicyError
from schemas.names import shorten

#: Without a deadline, a call that has not returned after this long is taken for a hang
#: (the episode fails with a "hung" reason). Generous on purpose: machine load never
#: decides a result; only a policy that truly stops answering meets it.
WATCHDOG_S = 300.0


def check_seconds(name: str, value: object) -> float:
    """A finite number of seconds > 0, or PolicyError naming it."""
    if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise PolicyError(f"{name} must be a finite number of seconds > 0, got {shorten(repr(value))}")
    return float(value)


def call_timeout(deadline_s: float | None) -> float:
    """How long a policy call may take: its deadline, or the watchdog where it has none."""
    return WATCHDOG_S if deadline_s is None else deadline_s
