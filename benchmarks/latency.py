"""What each frame of delay costs the built-in policies: S_loc and E_loc against ``--latency-frames``.

Evaluates ``--policies`` (default predictive and chase) on the first ``--episodes``
episodes of test-1k (90: ten per motion x interception cell) at each of ``--latencies``
frames (an action computed from frame t's observation takes effect at frame t + N), then
``scoring eval --latency-plot`` draws ``latency.png`` into ``--out`` and ``latency.json``
records the commit, dataset version and load, and each run's hash, wall time and scores.
Runs go to a temporary folder unless ``--runs`` is given; a run already there is reused.

    python benchmarks/latency.py --runs runs/latency
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
from scoring.cli import main as scoring_main  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policies", nargs="+", default=["predictive", "chase"])
    parser.add_argument("--latencies", nargs="+", type=int, default=[0, 2, 4, 8])
    parser.add_argument("--episodes", type=int, default=90)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=os.path.join(bench_setup.HERE, "results"))
    parser.add_argument("--runs", help="keep the runs in this folder")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    record: dict = {"benchmark": "latency", "slice": "test-1k", "episodes": args.episodes,
                    "start": bench_setup.provenance(), "runs": {}}
    with contextlib.ExitStack() as stack:
        runs = Path(args.runs) if args.runs else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        folders = []
        total = len(args.policies) * len(args.latencies)
        for policy in args.policies:
            for latency in args.latencies:
                folder = runs / f"{policy}-lat{latency}"
                folders.append(str(folder))
                if (folder / "catalog.json").is_file():
                    continue
                print(f"({len(folders)}/{total}) {policy} at latency {latency}: {args.episodes} episodes", file=sys.stderr)
                start = time.perf_counter()
                code = pipeline_main(["eval", "--policy", policy, "--episodes", str(args.episodes), "--workers",
                                      str(args.workers), "--latency-frames", str(latency), "--out", str(folder), "--quiet"])
                if code != 0:
                    return code
                record["runs"][folder.name] = {"seconds": round(time.perf_counter() - start, 1)}
        text = io.StringIO()
        with contextlib.redirect_stdout(text):
            code = scoring_main(["eval", *folders, "--json", "--latency-plot", str(out / "latency.png")])
        if code != 0:
            return code
        for scored in json.loads(text.getvalue()):
            name = scored["run"]
            catalog = json.loads((runs / name / "catalog.json").read_text())
            record["runs"].setdefault(name, {}).update(
                hash=catalog["hash"], commit=catalog["code"]["commit"], dataset_version=catalog["settings"]["dataset_version"],
                **{m: scored["metrics"][m] for m in ("S_hold", "S_loc", "E_loc")})
    record["end"] = bench_setup.provenance()
    (out / "latency.json").write_text(json.dumps(record, indent=1) + "\n")
    for name, run in record["runs"].items():
        print(f"{name}: S_hold {run['S_hold']:.1f}%, S_loc {run['S_loc']:.1f}%, E_loc {run['E_loc']:.2f}")
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
