"""The closed-loop results: evaluate the built-in policies on a test slice and score them.

Builds the ground truth of the first ``--episodes`` episodes of ``--slice`` (test-1k: 50
per motion x speed cell for 450), runs ``pipeline eval`` for oracle, predictive, chase,
still and the four blind reference policies on them (and the learned ``chunk_cnn`` when
torch and its checkpoint are present), then ``scoring eval --paper --chance BLIND...`` over
the folders (the GT row first, then the models, the chance row — the best blind score per
metric — and the paper's published rows), writing the terminal table, a Markdown table,
the per-episode rows and the radar plot into ``--out`` (default ``benchmarks/results``,
the files the docs show; test-1k's are ``table.*``, ``episodes.parquet``, ``radar.png``
and ``record.json``, another slice's carry its name, e.g. ``test_complex_table.md``).
``record.json`` holds the provenance the pages quote: the commit, the dataset version and
the load when the table was scored, and for each run its hash, commit, dataset version,
wall time and the load before and after it (kept in ``RUNS/timings.json``). The radar
draws families, not runs: the upper bound (GT and the oracle), the scripted baselines and
the learned models, each a band from its worst to its best member.
``--add-run FOLDER`` adds a run made elsewhere on the same episodes (the LeRobot ACT of
``benchmarks/lerobot_act.py``, evaluated in LeRobot's environment). Runs go
to a temporary folder unless ``--runs`` is given; a folder there that already holds a
``catalog.json`` is reused, so a kept ``--runs`` folder is re-scored in seconds.

    python benchmarks/closed_loop_results.py --episodes 450 --runs runs/test-1k
    python benchmarks/closed_loop_results.py --slice test-complex --episodes 300

Each build and evaluation shows its progress lines (per episode, at most one per 2 s) on
stderr unless ``--quiet``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
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
#: The radar's families (scoring eval --family): run names; the learned rows add the --add-run folders.
FAMILIES = (("upper bound", ("gt", "oracle")), ("scripted", ("predictive", "chase", "still")), ("learned", ("chunk_cnn",)))
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
        common = ["--episodes", str(args.episodes), "--workers", str(args.workers), *(["--quiet"] if args.quiet else [])]
        commands = {"gt": ["build", "--slice", args.slice, "--out", str(runs / "gt"), *common]}
        for policy in POLICIES:
            commands[policy] = ["eval", "--policy", policy, "--slice", args.slice, "--out", str(runs / policy), *common]
        if _learned_available():
            name, ref = LEARNED
            commands[name] = ["eval", "--policy", ref, "--slice", args.slice, "--out", str(runs / name), *common]
        timings_path = runs / "timings.json"
        timings = json.loads(timings_path.read_text()) if timings_path.is_file() else {}
        folders: dict[str, str] = {}
        blind = []
        for k, (name, command) in enumerate(commands.items()):
            folder = runs / name / args.slice if name == "gt" else runs / name
            if not (folder / "catalog.json").is_file():
                before, start = bench_setup.provenance(), time.perf_counter()
                if not args.quiet:
                    print(f"{name} ({k + 1}/{len(commands)}): pipeline {' '.join(command)}", file=sys.stderr)
                code = pipeline_main(command)
                if code != 0:
                    return code
                seconds = time.perf_counter() - start
                timings[name] = {"seconds": round(seconds, 1), "load_average_start": before["load_average"],
                                 "load_average_end": bench_setup.provenance()["load_average"], "date_utc": before["date_utc"]}
                timings_path.write_text(json.dumps(timings, indent=1, sort_keys=True))
                print(f"{name}: {args.episodes} episodes in {seconds:.1f} s", file=sys.stderr)
            if name in BLIND:
                blind.append(str(folder))
            else:
                folders[name] = str(folder)
        for folder in args.add_run:
            folders[Path(folder).name] = folder
        prefix = "" if args.slice == "test-1k" else args.slice.replace("-", "_") + "_"
        families = []
        for family, names in FAMILIES:
            names = (*names, *(Path(f).name for f in args.add_run)) if family == "learned" else names
            members = [folders[n] for n in names if n in folders]
            if len(members) > 1 or (members and family == "learned"):
                families += ["--family", family, *members]
        table = io.StringIO()
        with contextlib.redirect_stdout(table):
            code = scoring_main(["eval", *folders.values(), "--chance", *blind, "--plot", str(out / f"{prefix}radar.png"),
                                 *families, "--paper", "--markdown", str(out / f"{prefix}table.md"),
                                 "--episodes", str(out / f"{prefix}episodes.parquet")])
        (out / f"{prefix}table.txt").write_text(table.getvalue())
        record = {"benchmark": "closed_loop_results", "slice": args.slice, "episodes": args.episodes,
                  "scored": bench_setup.provenance(), "runs": {}}
        for name, folder in [*folders.items(), *((Path(b).name, b) for b in blind)]:
            catalog = json.loads((Path(folder) / "catalog.json").read_text())
            record["runs"][name] = {"hash": catalog["hash"], "policy": catalog.get("policy"),
                                    "commit": catalog["code"]["commit"],
                                    "dataset_version": catalog["settings"]["dataset_version"],
                                    "resolution": catalog["settings"]["resolution"], **timings.get(name, {})}
        (out / f"{prefix}record.json").write_text(json.dumps(record, indent=1) + "\n")
        print(table.getvalue())
    return code


if __name__ == "__main__":
    sys.exit(main())
