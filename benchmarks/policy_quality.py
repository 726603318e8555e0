"""How well the built-in policies do in the closed loop, per (motion type, setting) cell.

Runs each policy in :func:`pipeline.loop.wrappers.loop_env` on the first ``--per-cell`` test-1k
episodes of every one of the nine (motion type, interception setting) cells (test-1k
episode ``i`` belongs to cell ``i mod 9``) at ``--resolution`` px, then scores the
recordings with :func:`scoring.io.from_recordings` and :func:`scoring.report.score_run`
(exactly what ``scoring eval`` would print for the same frames, R_time's acting budget
included). The loop is the runner's, minus
its threads and deadlines: ``task`` carries ``intercept_time_s``.

Prints two lines per policy (success by motion type and setting, as S_loc/S_gra;
then the seven metrics of ``scoring``) and, as the last line, one JSON object
``{policy: {"episodes", "S_loc", "S_gra", "metrics", "by_motion", "by_setting",
"ms_per_step"}}`` with success rates in percent; ``ms_per_step`` is the policy's CPU
time per executed action. One process, one core.
Tiny check: ``python benchmarks/policy_quality.py --per-cell 1 --policies still oracle``.
"""

from __future__ import annotations

import argparse
import json
import time

import bench_setup  # noqa: F401  (puts the repository first on sys.path)
import numpy as np

from generators.recipe import spec_for  # noqa: E402
from pipeline.loop.env import horizon  # noqa: E402
from pipeline.loop.rollout import task_for  # noqa: E402
from pipeline.loop.wrappers import RecordEpisode, loop_env  # noqa: E402
from pipeline.policies.base import make_policy  # noqa: E402
from scoring.io import from_recordings  # noqa: E402
from scoring.metrics import METRIC_NAMES  # noqa: E402
from scoring.report import score_run  # noqa: E402


def predictive_without_text():
    """The predictive policy choosing its motion model by residual only (no text hint)."""
    from pipeline.policies.predictive import PredictivePolicy

    policy = PredictivePolicy(text_hint=False)
    policy.name = "predictive-no-text"
    return policy


def _rates(summary) -> dict:
    return {"S_loc": summary.metrics["S_loc"], "S_gra": summary.metrics["S_gra"]}


def rollout(env: RecordEpisode, policy, spec) -> tuple:
    obs, _ = env.reset(options={"spec": spec})
    policy.reset(task_for(spec, env.resolution, policy.privileged, horizon(spec)))
    steps, spent = 0, 0.0
    done = env.done
    while not done:
        start = time.process_time()
        action = np.asarray(policy.act(obs), dtype=np.float32)
        spent += time.process_time() - start
        for row in action.reshape(-1, 18):
            obs, _, terminated, truncated, _ = env.step(row)
            steps += 1
            done = terminated or truncated
            if done:
                break
    frames, _ = env.recording()
    return frames, steps, spent


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policies", nargs="+", default=["oracle", "still", "chase", "predictive"])
    parser.add_argument("--per-cell", type=int, default=5)
    parser.add_argument("--resolution", type=int, default=224)
    args = parser.parse_args(argv)
    indices = list(range(9 * args.per_cell))
    specs = [spec_for("test-1k", i) for i in indices]
    env = loop_env(args.resolution)
    results = {}
    for name in args.policies:
        policy = make_policy(name)
        recordings, steps, spent = [], 0, 0.0
        for spec in specs:
            frames, n, s = rollout(env, policy, spec)
            recordings.append(frames)
            steps, spent = steps + n, spent + s
        report = score_run(from_recordings(name, "test-1k", specs, recordings, policy=name))
        by_motion = {k: _rates(v) for k, v in report.breakdowns["by_motion"].items()}
        by_setting = {k: _rates(v) for k, v in report.breakdowns["by_speed"].items()}
        results[name] = {
            "episodes": len(specs),
            **_rates(report.overall),
            "metrics": {k: report.overall.metrics[k] for k in METRIC_NAMES},
            "by_motion": by_motion,
            "by_setting": by_setting,
            "ms_per_step": 1000.0 * spent / max(steps, 1),
        }
        r = results[name]
        print(f"{name:12s} episodes {r['episodes']:3d}  S_loc {r['S_loc']:5.1f}%  S_gra {r['S_gra']:5.1f}%  "
              f"policy {r['ms_per_step']:.2f} ms/step  " +
              "  ".join(f"{k} {v['S_loc']:.0f}/{v['S_gra']:.0f}" for k, v in {**by_motion, **by_setting}.items()),
              flush=True)
        print("    " + "  ".join(f"{k} {'-' if v is None else f'{v:.3f}'}" for k, v in r["metrics"].items()), flush=True)
    print(json.dumps(results, sort_keys=True))
    return results


if __name__ == "__main__":
    main()
