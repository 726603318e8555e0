"""The README's closed-loop results: evaluate the built-in policies on test-1k and score them.

Builds the ground truth of the first ``--episodes`` test-1k episodes (50 per motion x
speed cell for 450), runs ``pipeline eval`` for oracle, predictive, chase and still on
them (and the learned ``chunk_cnn`` when torch and its checkpoint are present), then
``scoring eval --paper`` over the folders (the GT row first, the paper's published rows
after ours), writing the terminal table, a Markdown table, the per-episode rows
(``episodes.parquet``) and the radar plot into ``--out`` (default
``benchmarks/results``, the files the README shows). Runs go to a temporary folder
unless ``--runs`` is given; a folder there that already holds a ``catalog.json`` is
reused.

    python benchmarks/closed_loop_results.py --episodes 450

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
from scoring.cli import main as scoring_main  # noqa: E402

POLICIES = ("oracle", "predictive", "chase", "still")
#: The learned baseline (benchmarks/train_chunk_cnn.py), when torch and its checkpoint are here.
LEARNED = ("chunk_cnn", "pipeline.policies.chunk_cnn:pretrained")


def _learned_available() -> bool:
    import importlib.util

    checkpoint = Path(bench_setup.HERE) / "results" / "chunk_cnn" / "model.pt"
    return importlib.util.find_spec("torch") is not None and checkpoint.is_file()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=450)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=os.path.join(bench_setup.HERE, "results"))
    parser.add_argument("--runs", help="keep the runs in this folder")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as stack:
        runs = Path(args.runs) if args.runs else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        common = ["--episodes", str(args.episodes), "--workers", str(args.workers), *(["--quiet"] if args.quiet else [])]
        commands = {"gt": ["build", "--slice", "test-1k", "--out", str(runs / "gt"), *common]}
        for policy in POLICIES:
            commands[policy] = ["eval", "--policy", policy, "--slice", "test-1k", "--out", str(runs / policy), *common]
        if _learned_available():
            name, ref = LEARNED
            commands[name] = ["eval", "--policy", ref, "--slice", "test-1k", "--out", str(runs / name), *common]
        folders = []
        for name, command in commands.items():
            folder = runs / name / "test-1k" if name == "gt" else runs / name
            if not (folder / "catalog.json").is_file():
                start = time.perf_counter()
                if not args.quiet:
                    print(f"{name} ({len(folders) + 1}/{len(commands)}): pipeline {' '.join(command)}", file=sys.stderr)
                code = pipeline_main(command)
                if code != 0:
                    return code
                print(f"{name}: {args.episodes} episodes in {time.perf_counter() - start:.1f} s", file=sys.stderr)
            folders.append(str(folder))
        table = io.StringIO()
        with contextlib.redirect_stdout(table):
            code = scoring_main(["eval", *folders, "--plot", str(out / "radar.png"), "--paper",
                                 "--markdown", str(out / "table.md"), "--episodes", str(out / "episodes.parquet")])
        (out / "table.txt").write_text(table.getvalue())
        print(table.getvalue())
    return code


if __name__ == "__main__":
    sys.exit(main())
