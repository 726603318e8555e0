"""Score loaded runs and present the results: JSON dict, terminal table, Markdown, CSV.

The JSON keys follow the data contract (``docs/concepts/data-contract.md``): ``episodes``, ``errors``, the
registered metrics (:mod:`scoring.registry`: the headline ``S_hold``, the paper's seven of
Table 3 and ``S_grasp_contact``), ``by_motion``, ``by_speed``; plus ``intervals``, ``by_object`` and counts.
Success rates are percentages; a metric with nothing to average over is ``null``.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from schemas.errors import SpecError
from schemas.names import shorten
from schemas.objects import OBJECTS
from schemas.scene import INTERCEPT_SECONDS, MOTION_TYPES
from scoring.chance import CHANCE_LABEL, ChanceRow
from scoring.hold import run_metrics
from scoring.io import RunData
from scoring.metrics import (
    DEFAULT_READING,
    EpisodeMetrics,
    Summary,
    aggregate,
    reading_named,
    wilson_interval,
)
from scoring.paper import PAPER_ROWS, paper_label
from scoring.registry import Metric, metric_names, table_metrics
from scoring.taxonomy import FAILURE_CLASSES, Failures, episode_failures
from scoring.text_table import aligned, packed, wrapped

#: Breakdowns: JSON key, the episode attribute grouped on, canonical group order, title.
BREAKDOWNS = (
    ("by_motion", "motion_type", MOTION_TYPES, "motion type"),
    ("by_speed", "intercept_setting", tuple(INTERCEPT_SECONDS), "interception setting"),
    ("by_object", "object", tuple(OBJECTS), "object"),
)
#: Groups always present in the JSON, even when empty, so that keys are stable.
ALWAYS_LISTED = {"by_motion", "by_speed"}


#: What an obstacle contact means for an episode's score (``scoring eval --obstacle-contact``):
#: ``fail`` (the default) scores it as a failure, ``report`` only counts it.
CONTACT_MODES = ("fail", "report")
DEFAULT_CONTACT = "fail"


@dataclass(frozen=True)
class RunReport:
    """A scored run: its label, overall summary and one summary per group of each breakdown."""

    label: str
    name: str
    slice: str
    policy: str | None
    privileged: bool
    overall: Summary
    breakdowns: dict[str, dict[str, Summary]]
    #: What was scored and each episode's facts (``scoring.episodes`` tabulates them).
    data: RunData = field(repr=False, compare=False)
    per_episode: EpisodeMetrics = field(repr=False, compare=False)
    #: Each episode's failure class and evidence (:mod:`scoring.taxonomy`).
    failures: Failures = field(repr=False, compare=False)
    #: ``report`` or ``fail`` (:data:`CONTACT_MODES`): how obstacle contacts were scored.
    obstacle_contact: str = DEFAULT_CONTACT
    #: The metric reading applied (:data:`scoring.metrics.READINGS`).
    reading: str = DEFAULT_READING

    @property
    def ground_truth(self) -> bool:
        return self.policy is None


def _groups(values: np.ndarray, canonical: Sequence[str], always: bool) -> list[str]:
    present = set(values.tolist())
    ordered = [g for g in canonical if always or g in present]
    return ordered + sorted(present - set(canonical))


def score_run(
    data: RunData, label: str | None = None, obstacle_contact: str = DEFAULT_CONTACT, reading: str = DEFAULT_READING
) -> RunReport:
    """Per-episode metrics of every episode, then the overall and grouped summaries.

    ``obstacle_contact``: ``fail`` (default) counts episodes whose hand touched an obstacle
    (the collision rate) and scores them as failures; ``report`` only counts them.
    ``reading`` names the rules for the paper's ambiguous metrics (:data:`scoring.metrics.READINGS`)."""
    if not isinstance(data, RunData):
        raise SpecError(f"data must be a RunData (scoring.io.load_run or from_recordings), got {shorten(repr(data))}")
    if label is not None and not isinstance(label, str):
        raise SpecError(f"label must be text or None, got {shorten(repr(label))}")
    if not isinstance(obstacle_contact, str) or obstacle_contact not in CONTACT_MODES:
        raise SpecError(f"obstacle_contact must be one of {CONTACT_MODES}, got {shorten(repr(obstacle_contact))}")
    rules = reading_named(reading)
    fails = obstacle_contact == "fail"
    per: EpisodeMetrics = run_metrics(data, rules)
    breakdowns: dict[str, dict[str, Summary]] = {}
    for key, attribute, canonical, _ in BREAKDOWNS:
        values = getattr(data, attribute)
        breakdowns[key] = {
            group: aggregate(per, data.error, values == group, min_clearance=data.min_clearance, contact_fails=fails)
            for group in _groups(values, canonical, key in ALWAYS_LISTED)
        }
    failures = episode_failures(
        per, data.offsets, data.palm_xyz, data.object_xyz, data.error, data.hover_offset, data.min_clearance, fails,
    )
    return RunReport(
        label=label or default_label(data),
        name=data.name,
        slice=data.slice,
        policy=data.policy,
        privileged=data.privileged,
        overall=aggregate(per, data.error, min_clearance=data.min_clearance, contact_fails=fails),
        obstacle_contact=obstacle_contact,
        reading=reading,
        breakdowns=breakdowns,
        data=data,
        per_episode=per,
        failures=failures,
    )


def group_failures(report: RunReport, key: str) -> dict[str, dict[str, int]]:
    """Failure class counts of each group of a breakdown (``by_motion``, ...), groups as in the summaries."""
    attribute = next(a for k, a, *_ in BREAKDOWNS if k == key)
    values = getattr(report.data, attribute)
    return {group: report.failures.counts(values == group) for group in report.breakdowns[key]}


def default_label(data: RunData) -> str:
    """The policy's name for rollouts (``(privileged)`` added when it read the ground-truth
    spec, the protocol in brackets when it was not the plain closed loop); ``GT (<folder>)``
    for a built ground-truth slice."""
    if not data.policy:
        return f"GT ({data.name})"
    label = f"{data.policy} (privileged)" if data.privileged else data.policy
    tags = protocol_tags(data.protocol)
    return f"{label} [{', '.join(tags)}]" if tags else label


def protocol_tags(protocol: dict | None) -> list[str]:
    """Short words for a run's protocol: latency, real time (flagged as not deterministic),
    perturbation and repeat, disturbances."""
    if not protocol:
        return []
    tags = []
    if protocol.get("latency_frames"):
        tags.append(f"latency {protocol['latency_frames']}")
    if protocol.get("realtime"):
        tags.append("REAL-TIME, not deterministic")
    if protocol.get("perturb"):
        tags.append(f"{protocol['perturb']}:{protocol.get('perturb_strength'):g} r{protocol.get('repeat', 0)}")
    if protocol.get("disturb"):
        tags.append("disturbed")
    return tags


def unique_labels(labels: Sequence[str], names: Sequence[str]) -> list[str]:
    """Labels made distinct: a clash gets the folder name, then a counter if still needed."""
    out = [lab if labels.count(lab) == 1 else f"{lab} ({name})" for lab, name in zip(labels, names)]
    seen: dict[str, int] = {}
    result = []
    for lab in out:
        seen[lab] = seen.get(lab, 0) + 1
        result.append(lab if out.count(lab) == 1 else f"{lab} #{seen[lab]}")
    return result


# --- JSON -------------------------------------------------------------------------


def _interval(value: tuple[float, float] | None) -> list[float] | None:
    return None if value is None else [float(value[0]), float(value[1])]


def summary_dict(summary: Summary, failures: dict[str, int] | None = None) -> dict[str, Any]:
    """A group's entry: counts, the eight metrics (flat) and their intervals (and with
    ``failures``, the episodes per failure class)."""
    out: dict[str, Any] = {
        "episodes": summary.episodes,
        "errors": summary.errors,
        "localized": summary.localized,
        "grasped": summary.grasped,
    }
    out.update(summary.metrics)
    out["intervals"] = {name: _interval(summary.intervals[name]) for name in metric_names()}
    out["averaged_over"] = dict(summary.averaged_over)
    if summary.obstacle_episodes:
        out["obstacles"] = obstacle_dict(summary)
    if failures is not None:
        out["failures"] = dict(failures)
    return out


def obstacle_dict(summary: Summary) -> dict[str, Any]:
    """Obstacle contact among a group's episodes with obstacles (the collision rate, percent)."""
    return {
        "episodes": summary.obstacle_episodes,
        "collisions": summary.collisions,
        "collision_rate": summary.collision_rate,
    }


def report_dict(report: RunReport) -> dict[str, Any]:
    """The ``scoring eval --json`` object of one run."""
    if not isinstance(report, RunReport):
        raise SpecError(f"report must be a RunReport (scoring.report.score_run), got {shorten(repr(report))}")
    overall = report.overall
    out: dict[str, Any] = {
        "label": report.label,
        "run": report.name,
        "slice": report.slice,
        "policy": report.policy,
        "ground_truth": report.ground_truth,
        "privileged": report.privileged,
        "protocol": report.data.protocol,
        "reading": report.reading,
        "episodes": overall.episodes,
        "errors": overall.errors,
        "localized": overall.localized,
        "grasped": overall.grasped,
        "metrics": dict(overall.metrics),
        "intervals": {name: _interval(overall.intervals[name]) for name in metric_names()},
        "averaged_over": dict(overall.averaged_over),
    }
    if overall.obstacle_episodes:
        out["obstacles"] = dict(obstacle_dict(overall), contact=report.obstacle_contact)
    out["failures"] = report.failures.counts()
    for key, *_ in BREAKDOWNS:
        counts = group_failures(report, key)
        out[key] = {group: summary_dict(s, counts[group]) for group, s in report.breakdowns[key].items()}
    return out


# --- tables -----------------------------------------------------------------------

def _arrow(metric: Metric) -> str:
    return "v" if metric.lower_is_better else "^"


def main_headers() -> tuple[str, ...]:
    """The main table's columns: the headline (S_hold) first, then the paper's seven and
    S_grasp_contact (:func:`scoring.registry.table_metrics`); a rate has its unit and a CI column."""
    return ("Run", "Episodes", "Errors") + tuple(
        header
        for m in table_metrics()
        for header in (
            (f"{m.name} ({m.unit}) {_arrow(m)}", f"{m.name} 95% CI") if m.is_rate else (f"{m.name} {_arrow(m)}",)
        ) + _coverage(m)
    )


def _coverage(metric: Metric) -> tuple[str, ...]:
    """The coverage column that follows ``metric`` in every table (``n_Q``), if any."""
    return (metric.coverage,) if metric.coverage else ()


def group_headers() -> tuple[str, ...]:
    """The breakdown tables' columns: one per metric, in the tables' order."""
    return ("Run", "Group", "Episodes", "Errors") + tuple(
        header for m in table_metrics() for header in (f"{m.name} ({m.unit})" if m.is_rate else m.name,) + _coverage(m)
    )
HEADLINE_NOTE = (
    "S_hold, the grasp that holds the object (the hold test), is the headline: blind play cannot win it. "
    "n_Q: the episodes Q_smooth and Q_line average (reading dyana: every episode, Q x success; "
    "paper, lenient: the successful trajectories only)."
)
LEGEND = (
    "^ higher is better, v lower is better; CI: 95% Wilson interval; - : nothing to average over; "
    "(privileged): the policy read the ground-truth spec (an upper bound, not a fair entry). " + HEADLINE_NOTE
)


PAPER_NOTE = (
    " paper T3/T4: the paper's published rows (Tables 3 and 4, its Unity suite), for reference; "
    "the paper has no S_hold or S_grasp_contact."
)
CHANCE_NOTE = (
    " chance (best blind): per metric, the best score of the --chance runs (blind policies on the same "
    "episodes); a score at or below it does not show that a model sees."
)


def reading_note(reports: Sequence[RunReport]) -> str:
    """The line saying which metric reading the rows follow (docs/reference/metrics.md)."""
    names = sorted({r.reading for r in reports})
    return f"Reading: {', '.join(names)} (scoring eval --reading; docs/reference/metrics.md, Readings)."


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _ci(value: tuple[float, float] | None) -> str:
    return "-" if value is None else f"[{value[0]:.1f}, {value[1]:.1f}]"


def _count(averaged_over: Mapping[str, int | None] | None, name: str) -> str:
    value = None if averaged_over is None else averaged_over.get(name)
    return "-" if value is None else str(value)


def _cells(metrics: dict[str, float | None], intervals: dict[str, tuple[float, float] | None] | None,
           averaged_over: Mapping[str, int | None] | None, with_ci: bool = True) -> list[str]:
    """The metric cells of a row (intervals None: "-" for every CI; ``with_ci`` False: the
    breakdowns' cells), each coverage column the count of its metric (``averaged_over``)."""
    cells = []
    for m in table_metrics():
        cells.append(_num(metrics[m.name]))
        if m.is_rate and with_ci:
            cells.append(_ci(None if intervals is None else intervals[m.name]))
        cells += [_count(averaged_over, m.name) for _ in _coverage(m)]
    return cells


def _main_row(report: RunReport) -> list[str]:
    s = report.overall
    return [report.label, str(s.episodes), str(s.errors)] + _cells(s.metrics, s.intervals, s.averaged_over)


def _paper_rows() -> list[list[str]]:
    """The paper's published rows (Tables 3 and 4) in the main table's columns."""
    return [[paper_label(row), "-", "-"] + _cells(row.metrics, None, None) for row in PAPER_ROWS]


def _chance_rows(chance: ChanceRow | None) -> list[list[str]]:
    if chance is None:
        return []
    return [[CHANCE_LABEL, str(chance.episodes), "-"] + _cells(chance.metrics, None, chance.averaged_over)]


def _main_rows(reports: Sequence[RunReport], paper: bool, chance: ChanceRow | None) -> list[list[str]]:
    return [_main_row(r) for r in reports] + _chance_rows(chance) + (_paper_rows() if paper else [])


def _group_rows(reports: Sequence[RunReport], key: str) -> list[list[str]]:
    rows = []
    for report in reports:
        for group, s in report.breakdowns[key].items():
            rows.append([report.label, group, str(s.episodes), str(s.errors)] + _cells(s.metrics, None, s.averaged_over, False))
    return rows


OBSTACLE_HEADERS = ("Run", "Episodes with obstacles", "Obstacle contacts", "Collision rate (%) v", "95% CI", "Contact")
OBSTACLE_NOTE = (
    "Obstacle contact: the hand's surface came within 0 units of an obstacle in an acting frame. "
    "Contact 'fail' (default): the episode counts as a failure; 'report': scored as usual (--obstacle-contact report)."
)


def _obstacle_rows(reports: Sequence[RunReport]) -> list[list[str]]:
    rows = []
    for r in reports:
        s = r.overall
        if s.obstacle_episodes:
            low, high = wilson_interval(s.collisions, s.obstacle_episodes)
            rows.append([r.label, str(s.obstacle_episodes), str(s.collisions), _num(s.collision_rate),
                         _ci((100.0 * low, 100.0 * high)), r.obstacle_contact])
    return rows


FAILURE_HEADERS = ("Run", "Group", "Episodes") + FAILURE_CLASSES
FAILURE_NOTE = (
    "Failures: one class per episode, the first that holds: success (the grasp held), policy_error, "
    "obstacle_contact (unless --obstacle-contact report), not_held (a contact grasp the hold test dropped), "
    "no_motion (palm moved <= 0.1), grasp_only (localized), "
    "timing (within 0.3 of the object's path 1-10 frames early or late), near_miss (within 0.6), "
    "perception_prediction (elsewhere). docs/reference/metrics.md, \"Why did it fail?\"."
)


def _failure_rows(reports: Sequence[RunReport]) -> list[list[str]]:
    """Per run: all episodes, then each motion type with episodes."""
    rows = []
    for r in reports:
        groups = [("all", r.failures.counts())] + [
            (group, counts) for group, counts in group_failures(r, "by_motion").items() if sum(counts.values())
        ]
        for group, counts in groups:
            rows.append([r.label, group, str(sum(counts.values()))] + [str(counts[c]) for c in FAILURE_CLASSES])
    return rows


def format_table(reports: Sequence[RunReport], paper: bool = False, chance: ChanceRow | None = None) -> str:
    """The terminal report: one row per run (the headline, then the paper's Table 3; with
    ``chance`` the chance row follows, with ``paper`` the published rows), then by motion
    and by interception, and obstacle contacts for runs with obstacles."""
    main_rows = _main_rows(reports, paper, chance)
    parts = [packed(main_headers(), main_rows, 1, [[1, 2], *_metric_columns(3, intervals=True)]),
             wrapped(LEGEND + (CHANCE_NOTE if chance else "") + (PAPER_NOTE if paper else "")),
             wrapped(reading_note(reports))]
    for key, _, _, title in BREAKDOWNS[:2]:
        parts += ["", f"By {title}:", packed(group_headers(), _group_rows(reports, key), 2,
                                              [[2, 3], *_metric_columns(4, intervals=False)])]
    obstacle_rows = _obstacle_rows(reports)
    if obstacle_rows:
        parts += ["", "Obstacles:", aligned(OBSTACLE_HEADERS, obstacle_rows), wrapped(OBSTACLE_NOTE)]
    parts += ["", "Failures:", packed(FAILURE_HEADERS, _failure_rows(reports), 2,
                                                 [[i] for i in range(2, len(FAILURE_HEADERS))]), wrapped(FAILURE_NOTE)]
    return "\n".join(parts) + "\n"


def _metric_columns(start: int, intervals: bool) -> list[list[int]]:
    """The column indices of each metric (its value, its interval where ``intervals``, its
    coverage), from column ``start``, in :func:`main_headers`' / :func:`group_headers`' order."""
    groups, at = [], start
    for m in table_metrics():
        size = 1 + (1 if intervals and m.is_rate else 0) + len(_coverage(m))
        groups.append(list(range(at, at + size)))
        at += size
    return groups


def _markdown_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    align = ["---"] + ["---:"] * (len(headers) - 1)
    return "\n".join([line(headers), "|" + "|".join(align) + "|", *(line(r) for r in rows)])


def markdown(reports: Sequence[RunReport], paper: bool = False, chance: ChanceRow | None = None) -> str:
    """Markdown export: the main table (the chance row, then with ``paper`` the paper's rows,
    after ours) and every breakdown."""
    headers = [h.replace(" ^", " ↑").replace(" v", " ↓") for h in main_headers()]
    main_rows = _main_rows(reports, paper, chance)
    parts = ["## Scores", "", _markdown_table(headers, main_rows), "",
             "↑ higher is better, ↓ lower is better. CI: 95% Wilson interval. -: nothing to average over. "
             + HEADLINE_NOTE
             + (CHANCE_NOTE if chance else "") + (PAPER_NOTE if paper else ""), "", reading_note(reports), ""]
    for key, _, _, title in BREAKDOWNS:
        parts += [f"### By {title}", "", _markdown_table(group_headers(), _group_rows(reports, key)), ""]
    obstacle_rows = _obstacle_rows(reports)
    if obstacle_rows:
        headers = [h.replace(" v", " ↓") for h in OBSTACLE_HEADERS]
        parts += ["### Obstacles", "", _markdown_table(headers, obstacle_rows), "", OBSTACLE_NOTE, ""]
    parts += ["### Failures", "", _markdown_table(FAILURE_HEADERS, _failure_rows(reports)), "", FAILURE_NOTE, ""]
    return "\n".join(parts)


def csv_fields() -> list[str]:
    """The CSV's columns: the row's run and group, counts, then each metric and its interval
    (and its coverage column, ``n_Q``)."""
    return ["label", "run", "slice", "policy", "reading", "breakdown", "group", "episodes", "errors", "localized",
            "grasped"] + [column for m in table_metrics() for column in (m.name, f"{m.name}_low", f"{m.name}_high")
                          + _coverage(m)]


def _csv_value(value: Any) -> Any:
    if value is None:
        return ""
    return repr(float(value)) if isinstance(value, float) else value


def _csv_row(report: RunReport, breakdown: str, group: str, s: Summary) -> dict[str, Any]:
    row: dict[str, Any] = {
        "label": report.label, "run": report.name, "slice": report.slice, "policy": report.policy or "",
        "reading": report.reading, "breakdown": breakdown, "group": group, "episodes": s.episodes, "errors": s.errors,
        "localized": s.localized, "grasped": s.grasped,
    }
    for name in metric_names():
        interval = s.intervals[name]
        row[name] = _csv_value(s.metrics[name])
        row[f"{name}_low"] = _csv_value(None if interval is None else float(interval[0]))
        row[f"{name}_high"] = _csv_value(None if interval is None else float(interval[1]))
    row.update({m.coverage: s.averaged_over.get(m.name, "") for m in table_metrics() if m.coverage})
    return row


def csv_text(reports: Sequence[RunReport], chance: ChanceRow | None = None) -> str:
    """CSV export in long form: one row per (run, breakdown, group), ``all`` for the overall
    row; with ``chance`` a last row labelled :data:`~scoring.chance.CHANCE_LABEL` (overall
    only, no intervals)."""
    buffer = io.StringIO()
    fields = csv_fields()
    writer = csv.DictWriter(buffer, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for report in reports:
        writer.writerow(_csv_row(report, "all", "all", report.overall))
        for key, *_ in BREAKDOWNS:
            for group, s in report.breakdowns[key].items():
                writer.writerow(_csv_row(report, key.removeprefix("by_"), group, s))
    if chance is not None:
        row: dict[str, Any] = {name: "" for name in fields}
        row.update({"label": CHANCE_LABEL, "run": " ".join(chance.runs), "slice": reports[0].slice if reports else "",
                    "reading": reports[0].reading if reports else "", "breakdown": "all", "group": "all",
                    "episodes": chance.episodes})
        row.update({name: _csv_value(chance.metrics[name]) for name in metric_names()})
        row.update({m.coverage: _csv_value(chance.averaged_over.get(m.name)) for m in table_metrics() if m.coverage})
        writer.writerow(row)
    return buffer.getvalue()
