"""The ``scoring`` command: ``scoring eval RUN [RUN ...] [--json] [--plot FILE.png]
[--markdown FILE.md] [--csv FILE.csv] [--episodes FILE.parquet|.csv] [--paper]
[--reading NAME] [--chance RUN [RUN ...]] [--family NAME RUN [RUN ...]]``.

Reads recorded shards only (never the simulator). Bad input (not a run folder, a
missing column, an empty run, a run missing some of its episodes 0..N-1) prints one line
on stderr and exits with code 2. Every output is checked before scoring and written by
:mod:`catalog.store.outputs`' rule: a file is replaced whole, a device or FIFO (``/dev/null``,
``/dev/stdout``) is written as such, and an empty path, a folder, a socket or a path inside
a run being read is refused.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from collections.abc import Sequence

from catalog.store.outputs import check_output, open_output
from schemas import cli
from schemas.errors import DyanaError
from schemas.names import shorten
from scoring.chance import ChanceRow, chance_by_group, chance_row, check_same_episodes
from scoring.episodes import check_episodes_path, write_episodes
from scoring.io import RunData, load_run
from scoring.metrics import DEFAULT_READING, READINGS
from scoring.report import (
    CONTACT_MODES,
    DEFAULT_CONTACT,
    RunReport,
    csv_text,
    default_label,
    format_table,
    markdown,
    report_dict,
    score_run,
    unique_labels,
)
from scoring.robustness import is_repeats_folder, load_repeats, robustness, robustness_lines


def _eval_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="+", metavar="RUN",
                   help="a folder with catalog.json and its shards, or a folder of repeats (repeats.json)")
    cli.add_json(p, "print JSON (an object for one run, a list for several; with repeats, "
                 "{\"runs\": [...], \"robustness\": [...]})")
    p.add_argument("--plot", type=cli.output_path, metavar="FILE.png", help="write a radar chart and per-motion bars")
    p.add_argument("--markdown", type=cli.output_path, metavar="FILE.md", help="write the tables as Markdown")
    p.add_argument("--csv", type=cli.output_path, metavar="FILE.csv", help="write every summary row as CSV")
    p.add_argument(
        "--paper", action="store_true",
        help="add the paper's published rows (Tables 3 and 4) to the table, Markdown and plot",
    )
    p.add_argument(
        "--obstacle-contact", choices=CONTACT_MODES, default=DEFAULT_CONTACT,
        help="an episode whose hand touched an obstacle: score it as a 'fail'ure (default) "
        "or only 'report' it in the collision rate",
    )
    p.add_argument(
        "--reading", choices=sorted(READINGS), default=DEFAULT_READING,
        help="how the metrics are read: 'dyana' (default: S_loc above the object's top, Q_smooth/Q_line x "
        "success over every episode), 'paper' (the paper's text only: S_loc in XZ, Q over the successful "
        "trajectories, n_Q of them) or 'lenient' (as 'paper' with minimum errors and zero steps dropped); "
        "docs/reference/metrics.md, Readings",
    )
    p.add_argument(
        "--chance", nargs="+", metavar="RUN",
        help="runs of blind reference policies on the same episodes (pipeline eval --policy blind-...): "
        "add a 'chance' row, the best blind score per metric",
    )
    p.add_argument(
        "--family", nargs="+", action="append", default=[], metavar="NAME RUN",
        help="with --plot: draw these RUNs (given above) as one series on the radar, NAME, a band from the "
        "worst to the best of them per metric (e.g. --family scripted runs/predictive runs/chase); repeatable",
    )
    p.add_argument("--latency-plot", type=cli.output_path, metavar="FILE.png",
                   help="write S_loc and E_loc against the runs' --latency-frames, one line per policy")
    p.add_argument(
        "--episodes", type=cli.output_path, metavar="FILE.parquet|.csv",
        help="write one row per episode (ids, motion, object, status, event frames, every metric)",
    )


def load_runs(runs: Sequence[str]) -> list[RunData]:
    """Load each run (a folder of repeats gives one run per repeat)."""
    data: list[RunData] = []
    for run in runs:
        if is_repeats_folder(run):
            data.extend(load_repeats(run).runs)
        else:
            data.append(load_run(run))
    return data


def episodes_note(data: Sequence[RunData]) -> str | None:
    """One line when the runs do not hold the same episodes (another slice, another count, a
    held-out split beside the public one): their rows then do not compare like for like."""
    sets = [frozenset(d.episode_id.tolist()) for d in data]
    if len(sets) < 2 or all(s == sets[0] for s in sets[1:]):
        return None
    common = frozenset.intersection(*sets)
    held = ", ".join(f"{d.name}: {len(s)} of {d.slice}" for d, s in zip(data[:4], sets[:4]))
    more = f", and {len(data) - 4} more" if len(data) > 4 else ""
    return (f"note: the runs hold different episodes ({held}{more}; {len(common)} in common): compare rows "
            f"over the same episodes (e.g. the same --slice and --episodes, and the same --test-seed-file)")


def score_all(data: Sequence[RunData], obstacle_contact: str = DEFAULT_CONTACT, reading: str = DEFAULT_READING) -> list[RunReport]:
    """Score loaded runs; labels are made unique across them."""
    labels = unique_labels([default_label(d) for d in data], [d.name for d in data])
    return [score_run(d, label, obstacle_contact, reading) for d, label in zip(data, labels)]


def evaluate(runs: Sequence[str], obstacle_contact: str = DEFAULT_CONTACT, reading: str = DEFAULT_READING) -> list[RunReport]:
    """Load and score each run (a folder of repeats gives one run per repeat); labels are
    made unique across the runs (:func:`episodes_note` says when they hold different episodes)."""
    return score_all(load_runs(runs), obstacle_contact, reading)


def chance_of(blind_runs: Sequence[str], scored: Sequence[RunReport], obstacle_contact: str, reading: str) -> ChanceRow:
    """The chance row of the blind runs, refused unless they hold the scored runs' episodes."""
    data = load_runs(blind_runs)
    check_same_episodes([(d.name, d.episode_id) for d in data], [(r.name, r.data.episode_id) for r in scored])
    blind = score_all(data, obstacle_contact, reading)
    row = chance_row([(r.label, r.overall) for r in blind])
    return dataclasses.replace(row, by_motion=chance_by_group([(r.label, r.breakdowns["by_motion"]) for r in blind]))


#: The output flags of ``scoring eval`` (attribute, flag).
OUTPUTS = (("markdown", "--markdown"), ("csv", "--csv"), ("episodes", "--episodes"),
           ("latency_plot", "--latency-plot"), ("plot", "--plot"))


def _write(path: str, text: str) -> None:
    try:
        with open_output(path, "w") as handle:
            handle.write(text)
    except OSError as exc:
        raise DyanaError(f"{shorten(path)}: cannot write: {exc.strerror or exc}") from None


def check_outputs(args: argparse.Namespace) -> None:
    """Before any scoring: every output flag given names a file that may be written
    (:func:`catalog.store.outputs.check_output`: not empty, not a folder, not inside a run read)."""
    for name, flag in OUTPUTS:
        path = getattr(args, name)
        if path is not None:
            check_output(path, list(args.runs) + list(args.chance or []), flag)
    if args.episodes is not None:
        check_episodes_path(args.episodes)


def check_families(specs: Sequence[Sequence[str]], runs: Sequence[str], plot: str | None) -> list[tuple[str, list[int]]]:
    """``--family NAME RUN...`` as (name, indices into ``runs``), refused in one line unless
    each RUN is one of ``runs``, in one family only, and --plot is given."""
    if specs and plot is None:
        raise DyanaError("--family groups runs on the radar of --plot: give --plot FILE.png too")
    where = {os.path.normpath(run): k for k, run in enumerate(runs)}
    taken: dict[int, str] = {}
    out = []
    for name, *members in specs:
        if not members:
            raise DyanaError(f"--family {shorten(name)}: name the runs it holds after the name")
        indices = []
        for run in members:
            k = where.get(os.path.normpath(run))
            if k is None:
                raise DyanaError(f"--family {shorten(name)}: {shorten(run)} is not one of the runs scored")
            if k in taken:
                raise DyanaError(f"--family {shorten(name)}: {shorten(run)} is already in family {shorten(taken[k])}")
            taken[k] = name
            indices.append(k)
        out.append((name, indices))
    return out


def cmd_eval(args: argparse.Namespace) -> int:
    check_outputs(args)
    family_specs = check_families(args.family, args.runs, args.plot)
    data, origin = [], []
    for k, run in enumerate(args.runs):
        loaded = load_runs([run])
        data += loaded
        origin += [k] * len(loaded)
    note = episodes_note(data)
    if note is not None:
        print(note, file=sys.stderr)
    reports = score_all(data, args.obstacle_contact, args.reading)
    if args.latency_plot is not None:
        from scoring.latency import latency_points

        if not latency_points(reports):  # before any output: an empty figure is no answer
            raise DyanaError("--latency-plot: no run to plot (a built slice's ground truth and --realtime runs "
                             "have no latency setting)")
    chance = None if not args.chance else chance_of(args.chance, reports, args.obstacle_contact, args.reading)
    robust = [robustness(load_repeats(run), args.reading, args.obstacle_contact == "fail")
              for run in args.runs if is_repeats_folder(run)]
    if args.json:
        payload = [report_dict(r) for r in reports]
        if robust or chance:
            wrapped: dict = {"runs": payload}
            if robust:
                wrapped["robustness"] = robust
            if chance:
                wrapped["chance"] = chance.as_dict()
            print(json.dumps(wrapped, indent=2, allow_nan=False))
        else:
            print(json.dumps(payload[0] if len(payload) == 1 else payload, indent=2, allow_nan=False))
    else:
        sys.stdout.write(format_table(reports, paper=args.paper, chance=chance))
        for report in robust:
            sys.stdout.write("\n" + "\n".join(robustness_lines(report)) + "\n")
    if args.markdown is not None:
        _write(args.markdown, markdown(reports, paper=args.paper, chance=chance))
    if args.csv is not None:
        _write(args.csv, csv_text(reports, chance))
    if args.episodes is not None:
        write_episodes(reports, args.episodes)
    if args.latency_plot is not None:
        from scoring.latency import plot_latency

        try:
            plot_latency(reports, args.latency_plot)
        except OSError as exc:
            raise DyanaError(f"{args.latency_plot}: cannot write: {exc.strerror or exc}") from None
    if args.plot is not None:
        from scoring.plot import Family, plot_runs

        try:
            families = [Family(name, tuple(i for i, k in enumerate(origin) if k in runs)) for name, runs in family_specs]
        except ValueError as exc:
            raise DyanaError(f"--family: {exc}") from None
        try:
            plot_runs(reports, args.plot, paper=args.paper, chance=chance, families=families)
        except OSError as exc:
            raise DyanaError(f"{args.plot}: cannot write: {exc.strerror or exc}") from None
    return 0


COMMANDS = (cli.Command("eval", "score one or more runs (or built slices for the GT row)", _eval_arguments, cmd_eval),)


def main(argv: Sequence[str] | None = None) -> int:
    return cli.run("scoring", "Score recorded rollouts with the paper's metrics.", COMMANDS, argv)


if __name__ == "__main__":
    sys.exit(main())
