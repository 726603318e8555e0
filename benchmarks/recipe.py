"""Benchmark: the ``catalog stats dyana-12m`` path on one core, against a bare baseline.

The stats path enumerates every episode's recipe choices (the first draws of each
episode's seeded stream, feasibility, redraws) and summarizes them. The baseline,
measured in the same run, only creates the same episodes' generators,
``np.random.default_rng(SeedSequence([slice_seed, i]))``; the floor builds them the
cheaper way (``Generator(PCG64(...))``, the same stream): what a recipe that makes one
generator per episode pays at least. The recipe computes those streams' first doubles
for many episodes at once instead (:mod:`generators.streams`), so it can be under the
floor (``ratio_to_floor`` < 1). The last line printed is JSON.

    python benchmarks/recipe.py                 # the full 184,718 episodes
    python benchmarks/recipe.py --episodes 2000 # a quick check
"""

from __future__ import annotations

import os

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402


def episode_seeds(episodes: int) -> list[tuple[int, int]]:
    """(slice seed, index) of the first ``episodes`` episodes of dyana-12m."""
    from schemas.slices import SLICES, get_slice

    pairs: list[tuple[int, int]] = []
    for name in get_slice("dyana-12m").parts:
        definition = SLICES[name]
        take = min(definition.episodes, episodes - len(pairs))
        pairs.extend((definition.seed, i) for i in range(take))
        if len(pairs) == episodes:
            break
    return pairs


def baseline(pairs: list[tuple[int, int]]) -> float:
    """``default_rng(SeedSequence([seed, i]))`` per episode, nothing else."""
    start = time.perf_counter()
    for seed, i in pairs:
        np.random.default_rng(np.random.SeedSequence([seed, i]))
    return time.perf_counter() - start


def floor(pairs: list[tuple[int, int]]) -> float:
    """The same generators built the cheaper way
    (``Generator(PCG64(SeedSequence(...)))``, the identical stream)."""
    start = time.perf_counter()
    for seed, i in pairs:
        np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, i])))
    return time.perf_counter() - start


def stats_path(episodes: int) -> tuple[float, dict]:
    from pipeline.cli_catalog import main

    argv = ["stats", "dyana-12m", "--json", "--episodes", str(episodes)]
    out = io.StringIO()
    start = time.perf_counter()
    with contextlib.redirect_stdout(out):
        code = main(argv)
    seconds = time.perf_counter() - start
    if code != 0:
        raise SystemExit(f"catalog {' '.join(argv)} exited with {code}")
    return seconds, json.loads(out.getvalue())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=None, help="first N episodes of dyana-12m (default: all)")
    parser.add_argument("--repeats", type=int, default=1, help="best of this many runs of each")
    args = parser.parse_args(argv)

    from generators.grids import config_pool
    from schemas.scene import MOTION_TYPES
    from schemas.slices import get_slice

    total = get_slice("dyana-12m").episodes
    episodes = total if args.episodes is None else args.episodes
    if not 1 <= episodes <= total or args.repeats < 1:
        parser.error(f"--episodes must be in [1, {total}] and --repeats >= 1")
    print(bench_setup.pin_one_core(), file=sys.stderr)

    start = time.perf_counter()
    for motion_type in MOTION_TYPES:
        config_pool(motion_type)
    grids_seconds = time.perf_counter() - start

    pairs = episode_seeds(episodes)
    base = min(baseline(pairs) for _ in range(args.repeats))
    cheapest = min(floor(pairs) for _ in range(args.repeats))
    runs = [stats_path(episodes) for _ in range(args.repeats)]
    seconds = min(r[0] for r in runs)
    stats = runs[0][1]
    if stats["total_episodes"] != episodes:
        raise SystemExit(f"stats enumerated {stats['total_episodes']} episodes, expected {episodes}")

    print(f"grid pools built in {grids_seconds:.2f} s (once per process, not in the timings below)", file=sys.stderr)
    print(f"baseline: {episodes:,} default_rng generators in {base:.2f} s", file=sys.stderr)
    print(f"floor: {episodes:,} Generator(PCG64) generators in {cheapest:.2f} s", file=sys.stderr)
    print(f"stats path: {episodes:,} episodes in {seconds:.2f} s ({stats['total_frames']:,} frames)", file=sys.stderr)
    print(
        json.dumps(
            {
                "benchmark": "recipe",
                "slice": "dyana-12m",
                "episodes": episodes,
                "seconds": round(seconds, 3),
                "specs_per_second": round(episodes / seconds, 1),
                "baseline_seconds": round(base, 3),
                "ratio_to_baseline": round(seconds / base, 3),
                "floor_seconds": round(cheapest, 3),
                "ratio_to_floor": round(seconds / cheapest, 3),
                "grid_seconds": round(grids_seconds, 3),
                "repeats": args.repeats,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
