"""Chance levels: the blind reference policies and the oracle on test-1k, scored every reading.

Runs each blind policy (``pipeline.policies.blind``) and the oracle through the closed loop
(:func:`pipeline.loop.wrappers.loop_env`, 224 px, the runner's :func:`~pipeline.loop.rollout.run_episode`)
on test-1k episodes ``0..--episodes-1``, scores the recordings as ``scoring eval`` would
(:func:`scoring.io.from_recordings`, :func:`scoring.report.score_run`) under every reading
(``scoring.metrics.READINGS``), builds the chance row (best blind value per metric), and writes
``benchmarks/results/blind_chance.json``: per policy and reading the eight metrics, the
episodes each mean averages and the headline's count, the chance row per reading, whether
the headline check holds (each blind policy <= 1% on the headline, the oracle >= 95%) and
where a blind policy beats the oracle under the default reading (``beats_oracle``); and
beside it ``blind_chance.md``, the table of the default reading with its chance row (the
results page shows it;
``--table-only`` rewrites it from the JSON). ``--runs FOLDER`` scores the runs that
``closed_loop_results.py --runs FOLDER`` kept (``FOLDER/oracle``, ``FOLDER/blind-...``: the
same episodes as the results table) instead of running the policies again. CPU-heavy (about 1 episode/s): run it alone,
e.g. ``nice python benchmarks/blind_chance.py``; tiny check:
``python benchmarks/blind_chance.py --episodes 3 --out /tmp/chance.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import bench_setup  # noqa: F401  (puts the repository first on sys.path)

from generators.recipe import spec_for  # noqa: E402
from pipeline.loop.rollout import run_episode  # noqa: E402
from pipeline.loop.wrappers import loop_env  # noqa: E402
from pipeline.policies.base import BLIND, make_policy  # noqa: E402
from scoring.chance import CHANCE_LABEL, chance_row  # noqa: E402
from scoring.io import from_recordings, load_run  # noqa: E402
from scoring.metrics import DEFAULT_READING, HEADLINE, READINGS  # noqa: E402
from scoring.registry import table_metrics  # noqa: E402
from scoring.report import score_run  # noqa: E402

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "blind_chance.json")
#: The headline's bound for blind play, and the oracle's floor (percent; issue 38).
BLIND_BOUND = 1.0
ORACLE_FLOOR = 95.0


def _cell(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def write_table(result: dict, json_path: str) -> None:
    """The default reading's scores and chance row as Markdown, beside the JSON (``.md``)."""
    reading = result.get("default_reading")
    if reading is None:
        raise SystemExit(f"{json_path}: written before the 'dyana' reading (issue 38), its 'paper' scores follow "
                         "the old rules (height band, Q from frame 0 to t_loc); run this script again")
    names = list(result["scores"]["oracle"][reading]["metrics"])
    lines = ["## Chance levels", "",
             f"test-1k episodes 0-{result['episodes'] - 1}, {result['resolution']} px, `{reading}` reading. "
             "The chance row is the best blind value per metric.", "",
             "| Policy | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    rows = [(name, result["scores"][name][reading]["metrics"]) for name in result["policies"]]
    rows.append((CHANCE_LABEL, result["chance"][reading]["metrics"]))
    lines += [f"| {name} | " + " | ".join(_cell(m[k]) for k in names) + " |" for name, m in rows]
    holds = "holds" if result["headline"]["holds"] else "FAILS"
    lines += ["", f"Headline check ({result['headline']['metric']} <= {result['headline']['blind_bound_percent']:g}% "
              f"for every blind policy, >= {result['headline']['oracle_floor_percent']:g}% for the oracle): {holds}.", ""]
    with open(os.path.splitext(json_path)[0] + ".md", "w") as handle:
        handle.write("\n".join(lines))


def run_policies(episodes: int, resolution: int, start: float) -> dict:
    """The blind policies' and the oracle's rollouts of test-1k episodes ``0..episodes-1``."""
    specs = [spec_for("test-1k", i) for i in range(episodes)]
    env = loop_env(resolution)
    data = {}
    try:
        for name in BLIND + ("oracle",):
            policy = make_policy(name)
            results = [run_episode(env, policy, spec) for spec in specs]
            errors = [r.error or None if not r.ok else None for r in results]
            data[name] = from_recordings(name, "test-1k", specs, [r.frames for r in results], policy=name, errors=errors)
            print(f"{name}: {time.perf_counter() - start:.0f} s", flush=True)
    finally:
        env.close()
    return data


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--out", default=OUT)
    parser.add_argument("--table-only", action="store_true", help="rewrite the .md table from the --out JSON")
    parser.add_argument("--runs", help="score closed_loop_results.py's kept runs in this folder instead of running")
    args = parser.parse_args()
    if args.table_only:
        with open(args.out) as handle:
            write_table(json.load(handle), args.out)
        return
    start = time.perf_counter()
    load_start = [round(v, 2) for v in os.getloadavg()]
    data = {}
    if args.runs:
        for name in BLIND + ("oracle",):
            data[name] = load_run(os.path.join(args.runs, name))
        args.episodes = len(data["oracle"].episode_id)
        with open(os.path.join(args.runs, "oracle", "catalog.json")) as handle:
            args.resolution = json.load(handle)["settings"]["resolution"]
    else:
        data = run_policies(args.episodes, args.resolution, start)
    scores: dict = {}
    chance: dict = {}
    for reading in READINGS:
        reports = {name: score_run(d, name, reading=reading) for name, d in data.items()}
        for name, report in reports.items():
            s = report.overall
            scores.setdefault(name, {})[reading] = {"metrics": s.metrics, "averaged_over": s.averaged_over,
                                                    "errors": s.errors,
                                                    f"{HEADLINE}_count": round(s.metrics[HEADLINE] * s.episodes / 100)}
        chance[reading] = chance_row([(name, reports[name].overall) for name in BLIND]).as_dict()
    default = {name: scores[name][DEFAULT_READING]["metrics"] for name in scores}
    holds = all(default[name][HEADLINE] <= BLIND_BOUND for name in BLIND) and default["oracle"][HEADLINE] >= ORACLE_FLOOR
    beats = [[name, m.name] for name in BLIND for m in table_metrics()
             if default[name][m.name] is not None and default["oracle"][m.name] is not None
             and (default[name][m.name] < default["oracle"][m.name] if m.lower_is_better
                  else default[name][m.name] > default["oracle"][m.name])]
    result = {
        "benchmark": "blind_chance", "slice": "test-1k", "episodes": args.episodes, "resolution": args.resolution,
        "policies": list(BLIND) + ["oracle"], "default_reading": DEFAULT_READING, "scores": scores, "chance": chance,
        "beats_oracle": beats,
        "headline": {"metric": HEADLINE, "blind_bound_percent": BLIND_BOUND, "oracle_floor_percent": ORACLE_FLOOR,
                     "holds": holds},
        "runs": args.runs, **{k: v for k, v in bench_setup.provenance().items() if k != "load_average"},
        "seconds": round(time.perf_counter() - start, 1), "load_average_start": load_start,
        "load_average_end": [round(v, 2) for v in os.getloadavg()],
    }
    with open(args.out, "w") as handle:
        json.dump(result, handle, indent=1)
        handle.write("\n")
    write_table(result, args.out)
    print(json.dumps({name: default[name][HEADLINE] for name in scores}), "holds:", holds, "beats the oracle:", beats)


if __name__ == "__main__":
    main()
