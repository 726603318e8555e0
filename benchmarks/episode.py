"""Benchmark: the episode stage (``pipeline.stages.episode``, no rendering) on one core.

A mix of recipe specs, the first ``--per-slice`` episodes of each of the nine atomic
slices, runs through ``episode(spec)``. The baseline, measured in the same run on the
same specs, only evaluates the object's motion at the same frame times
(``generators.motion.evaluate``): the least any episode stage must do. Specs are built
before timing; their cost (``generators.recipe.slice_specs``) is measured separately.
The projection weights each slice's mean time by its episode count in dyana-12m and
assumes two cores share the work evenly. The last line printed is JSON.

    python benchmarks/episode.py                  # 200 episodes per slice
    python benchmarks/episode.py --per-slice 10   # a quick check
"""

from __future__ import annotations

import os

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402


def timed(fn, items) -> float:
    start = time.perf_counter()
    for item in items:
        fn(item)
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-slice", type=int, default=200, help="episodes from each atomic slice (default 200)")
    parser.add_argument("--repeats", type=int, default=3, help="best of this many runs of each")
    parser.add_argument("--cores", type=int, default=2, help="cores assumed for the dyana-12m projection")
    args = parser.parse_args(argv)
    if args.per_slice < 1 or args.repeats < 1 or args.cores < 1:
        parser.error("--per-slice, --repeats and --cores must be >= 1")
    print(bench_setup.pin_one_core(), file=sys.stderr)

    from generators import motion
    from generators.ground_truth import frame_times
    from generators.recipe import slice_specs
    from pipeline.stages.episode import episode
    from schemas.slices import SLICES, get_slice

    parts = get_slice("dyana-12m").parts
    specs_by_slice = {}
    spec_seconds = 0.0
    for name in parts:
        start = time.perf_counter()
        specs_by_slice[name] = list(slice_specs(name, args.per_slice))
        spec_seconds += time.perf_counter() - start
    specs = [s for name in parts for s in specs_by_slice[name]]
    frames = sum(s.num_frames for s in specs)
    for s in specs[:: max(1, len(specs) // 50)]:  # warm caches (grasp sizing, motion compilation)
        episode(s)

    def bare(spec):
        motion.evaluate(spec.motion, frame_times(spec.num_frames))

    base = min(timed(bare, specs) for _ in range(args.repeats))
    seconds = min(timed(episode, specs) for _ in range(args.repeats))
    per_slice = {name: min(timed(episode, specs_by_slice[name]) for _ in range(args.repeats)) / args.per_slice for name in parts}

    total = get_slice("dyana-12m").episodes
    stage_total = sum(per_slice[name] * SLICES[name].episodes for name in parts)
    spec_each = spec_seconds / len(specs)
    projected = stage_total / args.cores
    projected_with_specs = (stage_total + spec_each * total) / args.cores

    print(f"baseline (motion only): {len(specs):,} episodes in {base:.3f} s", file=sys.stderr)
    print(f"episode stage: {len(specs):,} episodes ({frames:,} frames) in {seconds:.3f} s", file=sys.stderr)
    for name in parts:
        print(f"  {name:16s} {1e3 * per_slice[name]:.2f} ms/episode", file=sys.stderr)
    print(
        f"dyana-12m ({total:,} episodes) projected on {args.cores} cores: {projected:.0f} s "
        f"(+ recipe specs: {projected_with_specs:.0f} s)",
        file=sys.stderr,
    )
    print(
        json.dumps(
            {
                "benchmark": "episode",
                "episodes": len(specs),
                "frames": frames,
                "seconds": round(seconds, 4),
                "episodes_per_second": round(len(specs) / seconds, 1),
                "frames_per_second": round(frames / seconds, 1),
                "baseline_seconds": round(base, 4),
                "ratio_to_baseline": round(seconds / base, 3),
                "spec_ms_per_episode": round(1e3 * spec_each, 3),
                "ms_per_episode_by_slice": {k: round(1e3 * v, 3) for k, v in per_slice.items()},
                "dyana12m_episodes": total,
                "dyana12m_projected_seconds": round(projected, 1),
                "dyana12m_projected_seconds_with_specs": round(projected_with_specs, 1),
                "cores": args.cores,
                "repeats": args.repeats,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
