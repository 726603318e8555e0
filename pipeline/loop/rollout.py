"""One closed-loop episode: the environment, a policy and a per-call deadline.

:func:`run_episode` resets the environment with the spec (the observe window runs
inside the reset), gives the policy its task, then asks it for actions until the
episode terminates (grasp complete) or truncates (horizon). An action is one row
(18,) or a chunk (H, 18), executed open loop one row per frame (:func:`pipeline.loop.actions.run_chunk`,
which checks the whole chunk first). The environment is a recorded one
(:class:`pipeline.loop.wrappers.RecordEpisode`, e.g. from :func:`pipeline.loop.wrappers.loop_env`);
its protocol wrappers apply latency, perturbation and disturbance, and the episode
recorded is the one the environment ran (a disturbed spec under ``disturb``). The environment casts every action to float32,
as a trip over the wire does, so in-process and remote runs see identical numbers.

Faults fail the episode, never the run: an action that is not a finite (18,) or
(H, 18) array, an exception in ``reset``/``act``, a call that overruns
``deadline_s`` (calls run on a daemon worker thread, see
:mod:`pipeline.loop.worker_thread`) or a dropped connection gives status ``error`` with
the reason, and the frames recorded up to that point are kept (at least the first
acting frame, after the observe window).

Python cannot stop a thread: an in-process call past its deadline is abandoned and
keeps running in the background (the caller then discards that policy instance). A
model that may spin forever is better served with ``pipeline serve`` and evaluated
over ``ws://``, where the evaluator just drops the connection.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from pipeline.loop.actions import run_chunk
from pipeline.loop.deadlines import WATCHDOG_S, check_seconds
from pipeline.loop.env import horizon
from pipeline.loop.fault_text import raised
from pipeline.loop.worker_thread import CallTimeout, WorkerThread
from pipeline.loop.wrappers import RecordEpisode, note_policy_time
from pipeline.policies.base import Policy, Task
from schemas.errors import PolicyError
from schemas.frames import EpisodeFrames
from schemas.spec import EpisodeSpec
from schemas.versions import FPS


@dataclass(frozen=True)
class RolloutResult:
    """What one episode produced: its recording and how it ended.

    ``steps`` counts executed actions (frames advanced), ``calls`` the ``act`` calls made,
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


def task_for(spec: EpisodeSpec, resolution: int, privileged: bool, horizon: int) -> Task:
    """The task a policy's ``reset`` receives: what a model needs (the instruction, timing,
    the interception setting's time, image size, hand) and nothing that identifies the
    episode (no id, slice, seed or spec hash: a policy that could name its episode could
    look the answer up); the spec itself only for privileged policies, which are flagged."""
    task: Task = {
        "text": spec.text,
        "fps": FPS,
        "observe_frames": spec.observe_frames,
        "horizon": horizon,
        "resolution": resolution,
        "hand": spec.hand,
        "intercept_time_s": spec.intercept_time_s,
    }
    if privileged:
        task["spec"] = spec.to_json()
    return task


Arg = TypeVar("Arg")
Out = TypeVar("Out")


def call_policy(
    worker: WorkerThread, fn: Callable[[Arg], Out], arg: Arg, deadline_s: float | None, watchdog_s: float, what: str
) -> Out:
    """``fn(arg)`` on the worker thread; any fault (a timeout, an exception) as PolicyError."""
    try:
        return worker.call(fn, arg, timeout=watchdog_s if deadline_s is None else deadline_s)
    except CallTimeout:
        if deadline_s is None:
            raise PolicyError(f"policy {what} hung: no answer within the {watchdog_s:g} s watchdog") from None
        raise PolicyError(f"policy {what} exceeded its deadline of {deadline_s:g} s") from None
    except PolicyError:
        raise
    except Exception as exc:
        raise PolicyError(raised(what, exc)) from None


def run_episode(
    env: RecordEpisode, policy: Policy, spec: EpisodeSpec, deadline_s: float | None = None, watchdog_s: float = WATCHDOG_S
) -> RolloutResult:
    """Run ``policy`` on ``spec`` in ``env`` and return the recording (see the module docstring).

    Without ``deadline_s`` the result depends on the policy's answers only, never on how
    long they took; ``watchdog_s`` still ends a call that never returns (a "hung"
    error). Errors of the environment itself (a bad spec, a simulator failure)
    propagate; only the policy's faults become an ``error`` episode.
    """
    if deadline_s is not None:
        deadline_s = check_seconds("deadline", deadline_s)
    watchdog_s = check_seconds("watchdog", watchdog_s)
    obs, info = env.reset(options={"spec": spec})
    ran_spec = env.episode_spec
    assert ran_spec is not None  # set by reset
    spec = ran_spec
    worker = WorkerThread()
    status, reason = "ok", ""
    steps = calls = 0
    frame = int(obs["frame_index"])
    waited = 0.0
    try:
        # a policy that does not say is not privileged (the protocol's default, as describe_policy reads it)
        task = task_for(spec, env.resolution, bool(getattr(policy, "privileged", False)), horizon(spec))
        call_policy(worker, policy.reset, task, deadline_s, watchdog_s, "reset")
        done = env.done
        while not done:
            calls += 1
            start = time.perf_counter()
            raw = call_policy(worker, policy.act, obs, deadline_s, watchdog_s, "act")
            took = time.perf_counter() - start
            waited += took  # answered calls only: a failed call's time is no per-act time
            note_policy_time(env, took)  # a real-time protocol's latency (opt-in, recorded as not deterministic)
            ran = run_chunk(env, raw)
            obs, info, steps = ran.observation, ran.info, steps + ran.steps
            frame = int(obs["frame_index"])
            done = ran.terminated or ran.truncated
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
