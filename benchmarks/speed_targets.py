"""The three speed targets of the speed issue, measured in one run.

(a) ``catalog stats dyana-12m --json`` under 5 s on one core: the command as a fresh
    process pinned to one core (start-up, imports, enumerating the 184,718 episodes'
    recipe choices, printing), wall and CPU seconds, best and median of ``--repeats``;
    every repeat must print the same bytes (their sha256 is recorded).
(b) Scoring 1,000 rollouts under 1 s: a synthetic run of 1,000 rollouts x 70 frames in
    shards of 32 episodes (``benchmarks/scoring_speed.py``), or ``--run RUN``. Timed:
    ``load_run`` (the reader's checks included) + ``score_run`` + ``report_dict`` in this
    process, best of ``--repeats`` after one untimed call (the target); also the whole
    ``scoring eval RUN --json`` as a fresh process (start-up and imports included).
(c) The predictive policy's first ``act`` under 0.2 s at 224 px: best of ``--repeats``
    per episode over the first ``--episodes`` test-1k episodes
    (``benchmarks/closed_loop_speed.py``, which also times evaluation against building);
    median and p95, CPU and wall.

Wall times depend on what else runs on the machine: the load average (``os.getloadavg``)
is recorded before and after, and CPU times beside wall times. Prints a summary on
stderr and, as the last line, one JSON object with each target's numbers and whether
they meet it (``meets_wall``: (a) the best wall time, (b) the in-process time, (c) the
p95 of the per-episode best wall times; ``meets_cpu`` the same with CPU time).

    python benchmarks/speed_targets.py                  # ~2 minutes
    python benchmarks/speed_targets.py --repeats 1 --episodes 5
"""

from __future__ import annotations

import os

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import closed_loop_speed  # noqa: E402
import scoring_speed  # noqa: E402

STATS_LIMIT_S = 5.0
SCORING_LIMIT_S = 1.0
FIRST_ACT_LIMIT_S = 0.2


def _one_core() -> set[int]:
    return {min(os.sched_getaffinity(0))} if hasattr(os, "sched_getaffinity") else set()


def catalog_stats(repeats: int) -> dict:
    """(a): ``catalog stats dyana-12m --json`` as a fresh process on one core."""
    core = _one_core()
    env = {**os.environ, "PYTHONPATH": bench_setup.ROOT}
    walls, cpus, digests = [], [], set()
    for _ in range(repeats):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "pipeline.cli_catalog", "stats", "dyana-12m", "--json"],
            cwd=bench_setup.ROOT, env=env, capture_output=True, check=True,
            preexec_fn=(lambda: os.sched_setaffinity(0, core)) if core else None,
        )
        walls.append(time.perf_counter() - start)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append((after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime))
        digests.add(hashlib.sha256(done.stdout).hexdigest())
    if len(digests) != 1:
        raise SystemExit(f"catalog stats printed different outputs across repeats: {sorted(digests)}")
    return {
        "core": sorted(core),
        "repeats": repeats,
        "wall_best_s": round(min(walls), 3),
        "wall_median_s": round(statistics.median(walls), 3),
        "cpu_best_s": round(min(cpus), 3),
        "cpu_median_s": round(statistics.median(cpus), 3),
        "output_sha256": digests.pop(),
        "limit_s": STATS_LIMIT_S,
        "meets_wall": min(walls) < STATS_LIMIT_S,
        "meets_cpu": min(cpus) < STATS_LIMIT_S,
    }


def scoring(run: str | None, repeats: int) -> dict:
    """(b): scoring 1,000 rollouts (a synthetic run unless ``run``)."""
    if run is not None:
        out = scoring_speed.measure(Path(run), repeats)
    else:
        with tempfile.TemporaryDirectory(prefix="dyana-speed-targets-") as tmp:
            folder = scoring_speed.write_synthetic_run(Path(tmp) / "run", 1000, 70, 12_000, 32, 0)
            scoring_speed.score(folder)  # untimed: imports and first-call set-up
            out = scoring_speed.measure(folder, repeats)
    out.pop("metrics")
    return {"run": run or "synthetic", **out, "limit_s": SCORING_LIMIT_S, "meets_wall": out["seconds"] < SCORING_LIMIT_S}


def first_act(episodes: int, repeats: int) -> dict:
    """(c): the predictive policy's first act at 224 px."""
    out = closed_loop_speed.first_act(episodes, 224, repeats)
    return {
        **out,
        "limit_s": FIRST_ACT_LIMIT_S,
        "meets_wall": out["wall_p95_s"] < FIRST_ACT_LIMIT_S,
        "meets_cpu": out["cpu_p95_s"] < FIRST_ACT_LIMIT_S,
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="repeats of each timing (best kept)")
    parser.add_argument("--episodes", type=int, default=50, help="test-1k episodes of the first-act timing")
    parser.add_argument("--run", metavar="RUN", help="score this run folder instead of a synthetic one")
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.episodes < 1:
        parser.error("--repeats and --episodes must be >= 1")

    result: dict = {"benchmark": "speed_targets", "load_average_start": closed_loop_speed.load_average()}
    a = result["catalog_stats"] = catalog_stats(args.repeats)
    print(f"(a) catalog stats dyana-12m --json, one core: wall best {a['wall_best_s']:.2f} s, median "
          f"{a['wall_median_s']:.2f} s; CPU {a['cpu_best_s']:.2f} s (limit {STATS_LIMIT_S:g} s)", file=sys.stderr)
    b = result["scoring"] = scoring(args.run, args.repeats)
    print(f"(b) scoring {b['episodes']} rollouts ({b['frames']} frames, {b['shards']} shards): load + metrics + "
          f"report {b['seconds']:.3f} s (limit {SCORING_LIMIT_S:g} s); bare read {b['read_seconds']:.3f} s; "
          f"`scoring eval RUN --json` as a process {b['cli_seconds']:.2f} s", file=sys.stderr)
    c = result["first_act"] = first_act(args.episodes, args.repeats)
    print(f"(c) predictive first act, {c['episodes']} episodes at 224 px: CPU median {c['cpu_median_s']:.3f} s, "
          f"p95 {c['cpu_p95_s']:.3f} s; wall median {c['wall_median_s']:.3f} s, p95 {c['wall_p95_s']:.3f} s "
          f"(limit {FIRST_ACT_LIMIT_S:g} s)", file=sys.stderr)
    result["load_average_end"] = closed_loop_speed.load_average()
    result.update({k: v for k, v in bench_setup.provenance().items() if k != "load_average"})
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
