"""Cost of serving a policy over WebSocket (dyana/1) against calling it in process.

Starts ``pipeline serve --policy P --port 0`` in a subprocess, replays the same
observations (from short ``still`` rollouts of test-1k episodes) to the policy in
process and through :class:`~pipeline.remote.client.RemotePolicy`, and reports per ``act``
the in-process time and the round trip, separately for the first observation of an
episode (it carries the observe window) and for the others, and over all acts the
protocol overhead (round trip minus the server's own ``server_time_ms``). Then, with ``--eval-episodes``, evaluates the
same episodes in process and over the wire with ``pipeline.jobs.evaluate`` and checks
the shards are byte-identical.

    python benchmarks/remote.py [--policy predictive] [--resolution 224] [--episodes 4] [--eval-episodes 0]

Prints a summary, then one JSON line.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from generators.recipe import spec_for
from pipeline.loop.env import horizon
from pipeline.loop.rollout import task_for
from pipeline.loop.wrappers import loop_env
from pipeline.policies.base import make_policy
from pipeline.remote.client import RemotePolicy


def _observations(resolution: int, episodes: int) -> list[tuple[object, list[dict]]]:
    env = loop_env(resolution=resolution)
    still = make_policy("still")
    out = []
    for i in range(episodes):
        spec = spec_for("test-1k", i)
        obs, _ = env.reset(options={"spec": spec})
        seen = [obs]
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(still.act(obs))
            seen.append(obs)
            done = terminated or truncated
        out.append((spec, seen))
    return out


def _serve(policy: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [str(Path(sys.executable).parent / "pipeline"), "serve", "--policy", policy, "--port", "0"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )
    for line in proc.stderr:
        found = re.search(r"(ws://\S+:\d+)", line)
        if found:
            return proc, found.group(1)
    raise SystemExit(f"pipeline serve exited with {proc.wait()}")


def _time_acts(policy, data, resolution: int) -> tuple[list[float], list[float]]:
    first, rest = [], []
    for spec, seen in data:
        policy.reset(task_for(spec, resolution, policy.privileged, horizon(spec)))
        for k, obs in enumerate(seen):
            start = time.perf_counter()
            policy.act(obs)
            (first if k == 0 else rest).append((time.perf_counter() - start) * 1000.0)
    return first, rest


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="predictive")
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--eval-episodes", type=int, default=0)
    args = parser.parse_args(argv)

    data = _observations(args.resolution, args.episodes)
    local_first, local_rest = _time_acts(make_policy(args.policy), data, args.resolution)
    proc, url = _serve(args.policy)
    try:
        with RemotePolicy(url) as remote:
            remote_first, remote_rest = _time_acts(remote, data, args.resolution)
            timing = remote.timing()
        result = {
            "policy": args.policy,
            "resolution": args.resolution,
            "acts": len(local_first) + len(local_rest),
            "in_process_ms": float(np.mean(local_rest)),
            "round_trip_ms": float(np.mean(remote_rest)),
            "added_ms": float(np.mean(remote_rest) - np.mean(local_rest)),
            "all_acts_round_trip_ms": timing["round_trip_ms"],
            "all_acts_server_ms": timing["server_ms"],
            "protocol_overhead_ms": timing["round_trip_ms"] - timing["server_ms"],
            "first_in_process_ms": float(np.mean(local_first)),
            "first_round_trip_ms": float(np.mean(remote_first)),
            "ratio": float(np.mean(remote_rest) / max(np.mean(local_rest), 1e-9)),
        }
        if args.eval_episodes:
            from pipeline.jobs.evaluate import evaluate

            common = dict(episodes=args.eval_episodes, resolution=args.resolution, workers=2, progress=False, summary=False)
            with tempfile.TemporaryDirectory() as scratch:
                rates = {}
                for label, ref in (("in_process", args.policy), ("remote", url)):
                    start = time.perf_counter()
                    manifest = evaluate(ref, "test-1k", Path(scratch) / label, **common)
                    rates[label] = args.eval_episodes / (time.perf_counter() - start)
                    result[f"eval_{label}_hash"] = manifest.hash
            result["eval_in_process_episodes_per_s"] = rates["in_process"]
            result["eval_remote_episodes_per_s"] = rates["remote"]
            result["eval_identical"] = result.pop("eval_in_process_hash") == result.pop("eval_remote_hash")
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    print(
        f"{args.policy} at {args.resolution} px, {result['acts']} acts: in process {result['in_process_ms']:.2f} ms, "
        f"over loopback {result['round_trip_ms']:.2f} ms (+{result['added_ms']:.2f} ms; round trip minus server "
        f"time over all acts {result['protocol_overhead_ms']:.2f} ms); first act with the observe window "
        f"{result['first_in_process_ms']:.2f} -> {result['first_round_trip_ms']:.2f} ms",
        file=sys.stderr,
    )
    print(json.dumps(result, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
