"""Ground-truth quality: the paper's Table 3 metrics of the episode stage's own plans.

For each motion type, ``--per-type`` recipe episodes (split evenly over its fast,
medium and slow slices, the first ones of each) run through ``pipeline.stages.episode`` and
are scored by :mod:`scoring.metrics` exactly as rollouts are: over the acting frames
(phase != observe); E_loc is the minimum palm-to-object XZ distance, E_gra the minimum
fingertip-to-surface distance, Q_smooth/Q_line are measured on the palm path from the
first acting frame to the first localized frame inclusive. The paper's GT row is
printed beside. The last line printed is JSON.

    python benchmarks/gt_quality.py                 # 200 episodes per motion type
    python benchmarks/gt_quality.py --per-type 9    # a quick check

The irregular-to-regular setting (paper A.11, ``irregular-{fast,medium,slow}``) is scored
as a fourth type; ``--no-irregular`` leaves it out.
"""

from __future__ import annotations

import argparse
import json
import sys

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)

#: Table 3, row GT.
PAPER_GT = {"S_loc": 100.0, "E_loc": 0.16, "S_gra": 100.0, "E_gra": 0.09, "Q_smooth": 0.81, "Q_line": 0.96, "R_time": 0.16}


def split(total: int, parts: int) -> list[int]:
    return [total // parts + (1 if k < total % parts else 0) for k in range(parts)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-type", type=int, default=200, help="episodes per motion type (default 200)")
    parser.add_argument("--no-irregular", action="store_true", help="only the three Dyana-12M motion types")
    args = parser.parse_args(argv)
    if args.per_type < 3:
        parser.error("--per-type must be >= 3")

    from generators.recipe import slice_specs
    from pipeline.stages.episode import episode
    from schemas.scene import COMPLEX_MOTION_TYPES, INTERCEPT_SECONDS, MOTION_TYPES
    from scoring.io import from_recordings
    from scoring.metrics import METRIC_NAMES
    from scoring.report import score_run

    types = MOTION_TYPES if args.no_irregular else MOTION_TYPES + COMPLEX_MOTION_TYPES
    specs, recordings = [], []
    for motion_type in types:
        for setting, count in zip(INTERCEPT_SECONDS, split(args.per_type, len(INTERCEPT_SECONDS))):
            for spec in slice_specs(f"{motion_type}-{setting}", count):
                specs.append(spec)
                recordings.append(episode(spec))

    report = score_run(from_recordings("ground truth", "gt_quality", specs, recordings))
    result = {
        "episodes": len(specs),
        "metrics": report.overall.metrics,
        "by_motion": {m: report.breakdowns["by_motion"][m].metrics for m in types},
    }

    def fmt(value) -> str:
        return "   n/a" if value is None else f"{value:6.2f}" if abs(value) >= 10 else f"{value:6.3f}"

    print(f"{'':10s}" + "".join(f"{name:>9s}" for name in METRIC_NAMES), file=sys.stderr)
    print(f"{'paper GT':10s}" + "".join(f"{fmt(PAPER_GT.get(name)):>9s}" for name in METRIC_NAMES), file=sys.stderr)
    for label, metrics in [("all", result["metrics"])] + list(result["by_motion"].items()):
        print(f"{label:10s}" + "".join(f"{fmt(metrics[name]):>9s}" for name in METRIC_NAMES), file=sys.stderr)
    rounded = {
        "benchmark": "gt_quality",
        "episodes": result["episodes"],
        "metrics": {k: None if v is None else round(v, 4) for k, v in result["metrics"].items()},
        "by_motion": {
            m: {k: None if v is None else round(v, 4) for k, v in ms.items()} for m, ms in result["by_motion"].items()
        },
        "paper_gt": PAPER_GT,
    }
    print(json.dumps(rounded))
    return 0


if __name__ == "__main__":
    sys.exit(main())
