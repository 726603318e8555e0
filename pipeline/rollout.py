"""One closed-loop episode: the environment, a policy and a per-call deadline.

:func:`run_episode` resets the environment with the spec (the observe window runs
inside the reset), gives the policy its task, then asks it for actions until the
episode terminates (grasp complete) or truncates (horizon). An action is one row
(18,) or a chunk (H, 18), executed open loop one row per frame. Every action is
cast to float32 before it reaches the environment, exactly as it would be after a
trip over the wire, so in-process and remote runs see identical numbers.

Faults fail the episode, never the run: an action that is not a finite (18,) or
(H, 18) array, an exception in ``reset``/``act``, a call that overruns
``deadline_s`` (calls run on a daemon worker thread, see
:mod:`pipeline.worker_thread`) or a dropped connection gives status ``error`` with
the reason, and the frames recorded up to that point are kept (at least the first
acting frame, after the observe window).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.worker_thread import CallTimeout, WorkerThread
from schemas.errors import PolicyError
from schemas.frames import EpisodeFrames
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

ACTION_WIDTH = 18
#: Default per-call deadline (seconds) for a policy's ``reset`` and each ``act``.
DEFAULT_DEADLINE_S = 10.0


@dataclass(frozen=True)
class RolloutResult:
    """What one episode produced: its recording and how it ended.

    ``steps`` counts executed actions (frames advanced), ``calls`` the ``act`` calls,
    ``policy_s`` the seconds spent waiting for the policy (not recorded anywhere).
    """

    spec: EpisodeSpec
    frames: EpisodeFrames
    images: list[bytes]
    status: str
    error: str
    steps: int
    calls: int
    localized: bool
    grasped: bool
    policy_s: float

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def task_for(spec: EpisodeSpec, resolution: int, privileged: bool, horizon: int) -> dict[str, Any]:
    """The task a policy's ``reset`` receives; the spec itself only for privileged policies."""
    task: dict[str, Any] = {
        "text": spec.text,
        "fps": FPS,
        "observe_frames": spec.observe_frames,
        "horizon": horizon,
        "resolution": resolution,
        "hand": spec.hand,
    }
    if privileged:
        task["spec"] = spec.to_json()
    return task


def check_action(raw: Any) -> np.ndarray:
    """A policy's output as a float32 (H, 18) chunk, or PolicyError saying what is wrong."""
    try:
        action = np.asarray(raw, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise PolicyError(f"action is not a numeric array ({type(raw).__name__}: {exc})") from None
    if action.ndim == 1 and action.shape[0] == ACTION_WIDTH:
        action = action[None, :]
    elif not (action.ndim == 2 and action.shape[0] >= 1 and action.shape[1] == ACTION_WIDTH):
        raise PolicyError(f"action must have shape (18,) or (H, 18) with H >= 1, got {tuple(action.shape)}")
    bad = ~np.isfinite(action)
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise PolicyError(f"action contains NaN/inf (row {row}, column {col}: {action[row, col]})")
    return action


def _call(worker: WorkerThread, fn: Any, arg: Any, deadline_s: float, what: str) -> Any:
    try:
        return worker.call(fn, arg, timeout=deadline_s)
    except CallTimeout:
        raise PolicyError(f"policy {what} exceeded its deadline of {deadline_s:g} s") from None
    except PolicyError:
        raise
    except Exception as exc:
        text = str(exc)
        raise PolicyError(f"policy {what} raised {type(exc).__name__}" + (f": {text}" if text else "")) from None


def run_episode(env: Any, policy: Any, spec: EpisodeSpec, deadline_s: float = DEFAULT_DEADLINE_S) -> RolloutResult:
    """Run ``policy`` on ``spec`` in ``env`` and return the recording (see the module docstring).

    Errors of the environment itself (a bad spec, a simulator failure) propagate;
    only the policy's faults become an ``error`` episode.
    """
    if not (isinstance(deadline_s, (int, float)) and math.isfinite(deadline_s) and deadline_s > 0):
        raise PolicyError(f"deadline must be a finite number of seconds > 0, got {deadline_s!r}")
    from pipeline.env import horizon

    obs, info = env.reset(options={"spec": spec})
    worker = WorkerThread()
    status, reason = "ok", ""
    steps = calls = 0
    frame = int(obs["frame_index"])
    waited = 0.0
    try:
        task = task_for(spec, env.resolution, bool(getattr(policy, "privileged", False)), horizon(spec))
        _call(worker, policy.reset, task, deadline_s, "reset")
        done = False
        while not done:
            start = time.perf_counter()
            try:
                raw = _call(worker, policy.act, obs, deadline_s, "act")
            finally:
                waited += time.perf_counter() - start
            calls += 1
            chunk = check_action(raw)
            for row in chunk:
                obs, _reward, terminated, truncated, info = env.step(row)
                steps += 1
                frame = int(obs["frame_index"])
                if terminated or truncated:
                    done = True
                    break
    except PolicyError as exc:
        status, reason = "error", f"frame {frame}: {exc}"
    finally:
        if not worker.stuck:
            worker.close()
    frames, images = env.recording()
    return RolloutResult(
        spec=spec,
        frames=frames,
        images=list(images),
        status=status,
        error=reason,
        steps=steps,
        calls=calls,
        localized=bool(info.get("localized", False)),
        grasped=bool(info.get("grasped", False)),
        policy_s=waited,
    )
