"""Actions as the environment takes them: one (18,) row or an (H, 18) chunk, checked and
cast to float32 (what the recording keeps and a trip over the wire gives), and a
chunk's open-loop execution (:func:`run_chunk`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

from pipeline.loop.spaces import ACTION_WIDTH, Observation
from schemas.errors import PolicyError


def float32_copy(action: object) -> np.ndarray:
    """``action`` as a float32 array, or PolicyError: whatever the conversion raises (a
    tensor that refuses ``__array__``, ragged lists, ...) and complex values (whose
    imaginary part a cast would silently drop) are the policy's fault, not the run's.
    Values too large for float32 become inf, which the callers refuse. Always a copy, so
    a policy that refills the array it returned cannot rewrite recorded actions."""
    try:
        if np.iscomplexobj(action):  # type: ignore[arg-type]  # numpy's stub wants array-likes; any object is checked here
            raise PolicyError(f"action is not a real array (complex values: {np.asarray(action).dtype})")
        with np.errstate(over="ignore", invalid="ignore"):  # a copy: the policy may reuse its buffer
            return np.array(action, dtype=np.float32, copy=True)
    except PolicyError:
        raise
    except Exception as exc:
        raise PolicyError(f"action is not a numeric array ({type(action).__name__}: {type(exc).__name__}: {exc})") from None


def as_action(action: object) -> np.ndarray:
    """One action as float32 (18,), or PolicyError naming what is wrong."""
    arr = float32_copy(action)
    if arr.shape != (ACTION_WIDTH,):
        raise PolicyError(f"action must have shape ({ACTION_WIDTH},), got {tuple(arr.shape)}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise PolicyError(f"action contains NaN/inf at index {int(bad[0])} (value {arr[bad[0]]})")
    return arr


def as_chunk(action: object) -> np.ndarray:
    """An action or a chunk as float32 (H, 18) with H >= 1, or PolicyError."""
    arr = float32_copy(action)
    if arr.shape == (ACTION_WIDTH,):
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] != ACTION_WIDTH:
        raise PolicyError(f"action must have shape ({ACTION_WIDTH},) or (H, {ACTION_WIDTH}) with H >= 1, got {tuple(arr.shape)}")
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        row, col = (int(v) for v in bad[0])
        raise PolicyError(f"action contains NaN/inf at row {row}, column {col} (value {arr[row, col]})")
    return arr


@dataclass(frozen=True)
class ChunkResult:
    """What :func:`run_chunk` did: the last step's observation and info, the summed
    reward, how the episode stands, and how many rows ran."""

    observation: Observation
    reward: float
    terminated: bool
    truncated: bool
    #: Gymnasium's ``info`` dict (its keys: :class:`pipeline.loop.spaces.StepInfo`).
    info: dict[str, Any]
    steps: int


def run_chunk(env: gymnasium.Env[Observation, np.ndarray], action: object) -> ChunkResult:
    """Execute an action (18,) or a chunk (H, 18) open loop, one row per step, stopping
    at termination or truncation (later rows are dropped). The whole chunk is checked
    before any row runs: an invalid chunk raises PolicyError and changes nothing."""
    chunk = as_chunk(action)
    reward, steps = 0.0, 0
    for row in chunk:
        obs, r, terminated, truncated, info = env.step(row)
        reward += float(r)
        steps += 1
        if terminated or truncated:
            break
    return ChunkResult(obs, reward, terminated, truncated, info, steps)
