"""The closed-loop results: evaluate the built-in policies on a test slice and score them.

Builds the ground truth of the first ``--episodes`` episodes of ``--slice`` (test-1k: 50
per motion x speed cell for 450), runs ``pipeline eval`` for oracle, predictive, chase,
still and the four blind reference policies on them (and the learned ``chunk_cnn`` when
torch and its checkpoint are present), then ``scoring eval --paper --chance BLIND...`` over
the folders (the GT row first, then the models, the chance row — the best blind score per
metric — and the paper's published rows), writing the terminal table, a Markdown table,
the per-episode rows and the radar plot into ``--out`` (default ``benchmarks/results``,
the files the docs show; test-1k's are ``table.*``, ``episodes.parquet`` and
``radar.png``, another slice's carry its name, e.g. ``test_complex_table.md``).
``--add-run FOLDER`` adds a run made elsewhere on the same episodes (the LeRobot ACT of
``benchmarks/lerobot_act.py``, evaluated in LeRobot's environment). Runs go
to a temporary folder unless ``--runs`` is given; a folder there that already holds a
``catalog.json`` is reused, so a kept ``--runs`` folder is re-scored in seconds.

    python benchmarks/closed_loop_results.py --episodes 450 --runs runs/test-1k
    python benchmarks/closed_loop_results.py --slice test-complex --episodes 300

The committed results were run with ``--renderer full`` (dataset 3.0.0's frames, made
before the window renderer became the default); pass it to reproduce them exactly.

Each build and evaluation shows its progress lines (per episode, at most one per 2 s) on
stderr unless ``--quiet``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import tempfile
import time
from pathlib import Path

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)

from pipeline.cli import main as pipeline_main  # noqa: E402
from pipeline.policies.base import BLIND  # noqa: E402
from scoring.cli import main as scoring_main  # noqa: E402

POLICIES = ("oracle", "predictive", "chase", "still", *BLIND)
#: The learned baseline (benchmarks/train_chunk_cnn.py), when torch and its checkpoint are here.
LEARNED = ("chunk_cnn", "pipeline.policies.chunk_cnn:pretrained")


def _learned_available() -> bool:
    import importlib.util

    checkpoint = Path(bench_setup.HERE) / "results" / "chunk_cnn" / "model.pt"
    return importlib.util.find_spec("torch") is not None and checkpoint.is_file()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slice", default="test-1k", help="the test slice (default test-1k)")
    parser.add_argument("--episodes", type=int, default=450)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=os.path.join(bench_setup.HERE, "results"))
    parser.add_argument("--runs", help="keep the runs in this folder")
    parser.add_argument("--renderer", default="window",
                        help="the renderer of every build and run (default window, dataset 4.0.0; full: 3.0.0)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    parser.add_argument("--add-run", action="append", default=[], metavar="FOLDER",
                        help="also score this run, made elsewhere on the same episodes (a model evaluated in its "
                        "own environment: benchmarks/lerobot_act.py), after the built-in rows; repeatable")
    args = parser.parse_args(argv)
    for folder in args.add_run:
        if not (Path(folder) / "catalog.json").is_file():
            parser.error(f"--add-run takes a run's folder (with its catalog.json), got {folder[:200]!r}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as stack:
        runs = Path(args.runs) if args.runs else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        common = ["--episodes", str(args.episodes), "--workers", str(args.workers), "--renderer", args.renderer,
                  *(["--quiet"] if args.quiet else [])]
        commands = {"gt": ["build", "--slice", args.slice, "--out", str(runs / "gt"), *common]}
        for policy in POLICIES:
            commands[policy] = ["eval", "--policy", policy, "--slice", args.slice, "--out", str(runs / policy), *common]
        if _learned_available():
            name, ref = LEARNED
            commands[name] = ["eval", "--policy", ref, "--slice", args.slice, "--out", str(runs / name), *common]
        folders, blind = [], []
        for name, command in commands.items():
            folder = runs / name / args.slice if name == "gt" else runs / name
            if not (folder / "catalog.json").is_file():
                start = time.perf_counter()
                if not args.quiet:
                    print(f"{name} ({len(folders) + 1}/{len(commands)}): pipeline {' '.join(command)}", file=sys.stderr)
                code = pipeline_main(command)
                if code != 0:
                    return code
                print(f"{name}: {args.episodes} episodes in {time.perf_counter() - start:.1f} s", file=sys.stderr)
            (blind if name in BLIND else folders).append(str(folder))
        folders += args.add_run
        prefix = "" if args.slice == "test-1k" else args.slice.replace("-", "_") + "_"
        table = io.StringIO()
        with contextlib.redirect_stdout(table):
            code = scoring_main(["eval", *folders, "--chance", *blind, "--plot", str(out / f"{prefix}radar.png"),
                                 "--paper", "--markdown", str(out / f"{prefix}table.md"),
                                 "--episodes", str(out / f"{prefix}episodes.parquet")])
        (out / f"{prefix}table.txt").write_text(table.getvalue())
        print(table.getvalue())
    return code


if __name__ == "__main__":
    sys.exit(main())
