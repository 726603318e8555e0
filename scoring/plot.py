"""One PNG comparing runs, drawn for a paper's column (3.5 in wide, 7 pt text, 300 dpi):

* a radar over the paper's seven Table 3 metrics in the style of its Figure 1 (every
  axis normalised to [0, 1], outward is better), each run with its own colour
  (Okabe-Ito, colour-blind safe), line style and marker so that runs lying on top of
  each other stay distinguishable. A *family* (``scoring eval --family``: the scripted
  baselines, the learned models) is one series: a band from its worst to its best
  member on each axis and a line at the best, so a radar of many runs stays a few
  shapes at a column's width; with ``paper=True`` a second radar holds the paper's
  published rows the same way (its GT, its Table 3 VLAs, its Table 4 VLMs);
* bars of the three success rates per motion type with their Wilson intervals and a
  legend; a rate of 0 is drawn as a visible stub labelled 0, a group without
  episodes in one run is labelled n/a, a group no run holds is left out.

Given a chance row (``scoring eval --chance``), the radar shades the area blind play
reaches and each motion type's bars carry a dashed line at its best blind rate: a run
inside the shade, or a bar under its line, does not show that the model sees.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from catalog.store.outputs import open_output  # noqa: E402
from scoring.chance import CHANCE_LABEL, ChanceRow  # noqa: E402
from scoring.paper import PAPER_ROWS  # noqa: E402
from scoring.registry import Metric, registered, table_metrics  # noqa: E402
from scoring.report import RunReport  # noqa: E402

#: The radar's axes: the paper's Table 3 columns (the registry's ``on_radar`` metrics);
#: errors are shown as 1 / (1 + E).
RADAR_METRICS = tuple(m.name for m in registered() if m.on_radar)
#: Okabe-Ito colours, then line styles and markers cycled independently of them.
COLOURS = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#CC79A7", "#56B4E9", "#F0E442", "#000000")
STYLES = ("-", "--", ":", "-.")
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
PAPER_COLOURS = ("#444444", "#777777", "#999999", "#BBBBBB")
CHANCE_COLOUR = "#9A9A9A"
COLUMN_WIDTH_IN = 3.5
FONT_PT = 7


@dataclass(frozen=True)
class _Series:
    """One radar series: a run, or a family (``low`` holds its worst member per axis)."""

    label: str
    metrics: dict[str, float | None]
    colour: str
    style: str
    marker: str
    width: float
    low: dict[str, float | None] | None = None


@dataclass(frozen=True)
class Family:
    """Runs drawn on the radar as one series: ``members`` are indices into the reports."""

    name: str
    members: tuple[int, ...]

    def __post_init__(self) -> None:
        if not self.name.strip() or len(self.name) > 60:
            raise ValueError(f"a family's name is 1-60 characters, got {self.name[:80]!r}")
        if not self.members or len(set(self.members)) != len(self.members):
            raise ValueError(f"family {self.name!r} needs distinct members, got {self.members!r}")


def radar_metrics() -> tuple[Metric, ...]:
    """The radar's axes: the registered metrics drawn on it (:attr:`Metric.on_radar`), in order."""
    return tuple(m for m in registered() if m.on_radar)


def radar_values(metrics: dict[str, float | None]) -> list[float]:
    """The radar's metrics mapped to [0, 1], higher better; a missing metric is NaN (not drawn)."""
    return [m.radar_value(metrics.get(m.name)) for m in radar_metrics()]


def envelope(members: Sequence[dict[str, float | None]]) -> tuple[dict[str, float | None], dict[str, float | None]]:
    """A family's (best, worst) per metric, best meaning outward on the radar; a metric no
    member has stays None (a gap, never a 0)."""
    best: dict[str, float | None] = {}
    worst: dict[str, float | None] = {}
    for metric in radar_metrics():
        values = [v for m in members if (v := m.get(metric.name)) is not None]
        if not values:
            best[metric.name] = worst[metric.name] = None
            continue
        ranked = sorted(values, key=lambda v: metric.radar_value(v))
        worst[metric.name], best[metric.name] = ranked[0], ranked[-1]
    return best, worst


def _family_series(label: str, members: Sequence[dict[str, float | None]], k: int, width: float) -> _Series:
    best, worst = envelope(members)
    return _Series(label, best, COLOURS[k % len(COLOURS)], STYLES[k % len(STYLES)], MARKERS[k % len(MARKERS)],
                   width, low=worst if len(members) > 1 else None)


def _series(reports: Sequence[RunReport], families: Sequence[Family] = ()) -> list[_Series]:
    """One series per family (at its first member's place) and per run in no family."""
    owner = {i: f for f in families for i in f.members}
    out: list[_Series] = []
    for i, report in enumerate(reports):
        family = owner.get(i)
        if family is None:
            out.append(_family_series(report.label, [report.overall.metrics], len(out), 1.6 if i == 0 else 1.1))
        elif family.members[0] == i:
            names = ", ".join(reports[j].label for j in family.members)
            out.append(_family_series(f"{family.name}: {names}", [reports[j].overall.metrics for j in family.members],
                                      len(out), 1.1))
    return out


def _paper_series() -> list[_Series]:
    """The paper's published rows on a radar of their own (beside the runs they would bury),
    as three series: its GT, its Table 3 policy models, its Table 4 VLMs."""
    groups = [("paper GT", [r for r in PAPER_ROWS if r.label == "GT"]),
              ("paper T3 VLAs", [r for r in PAPER_ROWS if r.table == 3 and r.label != "GT"]),
              ("paper T4 VLMs", [r for r in PAPER_ROWS if r.table == 4])]
    out = []
    for k, (name, rows) in enumerate(groups):
        label = name if len(rows) == 1 else f"{name} ({len(rows)}: best line, range shaded)"
        best, worst = envelope([r.metrics for r in rows])
        out.append(_Series(label, best, PAPER_COLOURS[k % len(PAPER_COLOURS)], STYLES[k % len(STYLES)],
                           MARKERS[k % len(MARKERS)], 1.0, low=worst if len(rows) > 1 else None))
    return out


def _radar(ax, series: Sequence[_Series], chance: ChanceRow | None = None) -> None:
    axes = radar_metrics()
    angles = np.linspace(0.0, 2.0 * np.pi, len(axes), endpoint=False)
    closed = np.concatenate([angles, angles[:1]])
    if chance is not None:
        values = radar_values(chance.metrics)
        ax.fill(closed, values + values[:1], color=CHANCE_COLOUR, alpha=0.35, linewidth=0.0, label=CHANCE_LABEL)
    for s in series:
        values = radar_values(s.metrics)
        if s.low is not None:
            low = radar_values(s.low)
            ax.fill_between(closed, low + low[:1], values + values[:1], color=s.colour, alpha=0.18, linewidth=0.0)
        ax.plot(closed, values + values[:1], color=s.colour, linestyle=s.style, linewidth=s.width,
                marker=s.marker, markersize=3.0, label=s.label)
    ax.set_theta_offset(np.pi / 2.0)
    ax.set_theta_direction(-1)
    ax.set_xticks(angles)
    ax.set_xticklabels([])
    for angle, metric in zip(angles, axes):
        side = np.sin(angle)
        ha = "left" if side > 0.2 else "right" if side < -0.2 else "center"
        va = "bottom" if np.cos(angle) > 0.5 else "top" if np.cos(angle) < -0.5 else "center"
        ax.text(angle, 1.1, metric.radar_label, ha=ha, va=va, fontsize=FONT_PT)
    ax.set_ylim(0.0, 1.0)
    ax.set_yticks([0.25, 0.5, 0.75, 1.0])
    ax.set_yticklabels(["", "0.5", "", "1"], fontsize=FONT_PT - 1, color="grey")
    ax.set_rlabel_position(180.0 / len(axes))
    ax.grid(linewidth=0.4)


def _episodes(report: RunReport, group: str) -> int:
    summary = report.breakdowns["by_motion"].get(group)
    return 0 if summary is None else summary.episodes


def bar_groups(reports: Sequence[RunReport]) -> list[str]:
    """The motion types the bars show, in the reports' order: those some run holds episodes
    of (test-complex has no linear ones: they take no room), or all when none does."""
    groups: list[str] = []
    for report in reports:
        groups += [g for g in report.breakdowns["by_motion"] if g not in groups]
    held = [g for g in groups if any(_episodes(r, g) for r in reports)]
    return held or groups


def _bars(ax, reports: Sequence[RunReport], metric: str, show_groups: bool, chance: ChanceRow | None = None) -> None:
    groups = bar_groups(reports)
    x = np.arange(len(groups))
    width = 0.8 / len(reports)
    for i, report in enumerate(reports):
        colour = COLOURS[i % len(COLOURS)]
        centres = x - 0.4 + width * (i + 0.5)
        heights, low, high = [], [], []
        for centre, group in zip(centres, groups):
            summary = report.breakdowns["by_motion"].get(group)
            value = None if summary is None or summary.episodes == 0 else summary.metrics[metric]
            interval = None if value is None or summary is None else summary.intervals[metric]
            heights.append(0.0 if value is None else value)
            # Wilson bounds at 0% or 100% equal the rate up to rounding: clamp at 0.
            low.append(0.0 if interval is None or value is None else max(value - interval[0], 0.0))
            high.append(0.0 if interval is None or value is None else max(interval[1] - value, 0.0))
            if value is None:
                ax.text(centre, 2.0, "n/a", ha="center", va="bottom", rotation=90, fontsize=FONT_PT - 2, color=colour)
            elif value == 0.0:
                ax.plot([centre - width * 0.45, centre + width * 0.45], [0.8, 0.8], color=colour, linewidth=2.0)
                ax.text(centre, 3.0, "0", ha="center", va="bottom", fontsize=FONT_PT - 1, color=colour)
        ax.bar(centres, heights, width, yerr=[low, high], color=colour, capsize=1.5, label=report.label,
               error_kw={"linewidth": 0.6, "capthick": 0.6}, hatch=None, edgecolor="none")
    marked = [(c, v) for c, g in zip(x, groups) if chance is not None and (v := chance.by_motion.get(g, {}).get(metric)) is not None]
    for i, (centre, value) in enumerate(marked):
        ax.plot([centre - 0.45, centre + 0.45], [value, value], color="black", linestyle=(0, (2, 1)),
                linewidth=0.8, label=CHANCE_LABEL if i == 0 else None)
    ax.set_xticks(x)
    ax.set_xticklabels(groups if show_groups else [], fontsize=FONT_PT)
    ax.set_ylim(0.0, 112.0)
    ax.set_yticks([0, 50, 100])
    ax.tick_params(labelsize=FONT_PT, length=2)
    ax.set_ylabel(f"{metric} (%)", fontsize=FONT_PT)
    ax.grid(axis="y", linewidth=0.3)
    ax.set_axisbelow(True)


def _legend_columns(series: Sequence[_Series]) -> int:
    """Two legend columns, or one when a label (a family lists its members) would not fit half
    a column's width."""
    return 1 if max((len(s.label) for s in series), default=0) > 30 else 2


def plot_runs(
    reports: Sequence[RunReport], path: str | os.PathLike[str], paper: bool = False, chance: ChanceRow | None = None,
    families: Sequence[Family] = (),
) -> None:
    """Write the radar and the per-motion success bars of ``reports`` to a PNG (atomically),
    with ``chance`` shaded on the radar and marked on the bars and each of ``families`` one
    series on the radar."""
    if not reports:
        raise ValueError("nothing to plot: no runs")
    if any(i >= len(reports) or i < 0 for f in families for i in f.members):
        raise ValueError(f"a family's member is not one of the {len(reports)} runs")
    series = _series(reports, families)
    radars = [(series, chance, "All metrics, outward is better")]
    if paper:
        radars.append((_paper_series(), None, "The paper's published rows (its Unity suite), for scale"))
    columns = [_legend_columns(entries) for entries, _, _ in radars]
    legend_rows = [-(-(len(entries) + (shade is not None)) // n) for (entries, shade, _), n in zip(radars, columns)]
    bar_entries = len(reports) + (chance is not None and bool(chance.by_motion))
    bar_rows = -(-bar_entries // min(bar_entries, 3))
    # each radar with its legend under it; under the last, room for the bars' title and legend
    rates = [m.name for m in table_metrics() if m.is_rate]
    heights: list[float] = []
    for k, rows in enumerate(legend_rows):
        heights += [3.0, 0.2 * rows + 0.15 + (0.45 if k < len(legend_rows) - 1 else 0.0)]  # room for the next title
    heights[-1] += 0.12 * bar_rows + 0.3  # the bars' title and legend sit above their first axes
    heights += [1.05] * len(rates)
    figure = plt.figure(figsize=(COLUMN_WIDTH_IN, sum(heights) + 0.5), dpi=300)
    try:
        grid = figure.add_gridspec(len(heights), 1, height_ratios=heights, hspace=0.35)
        for k, (entries, shade, title) in enumerate(radars):
            radar = figure.add_subplot(grid[2 * k, 0], projection="polar")
            _radar(radar, entries, shade)
            radar.set_title(title, fontsize=FONT_PT + 1, pad=22)
            legend_ax = figure.add_subplot(grid[2 * k + 1, 0])
            legend_ax.axis("off")
            handles, labels = radar.get_legend_handles_labels()
            legend_ax.legend(handles, labels, loc="center", ncol=columns[k], fontsize=FONT_PT - 0.5, frameon=False,
                             handlelength=2.6, columnspacing=1.0)
        first_bar = 2 * len(radars)
        for k, metric in enumerate(rates):
            ax = figure.add_subplot(grid[first_bar + k, 0])
            _bars(ax, reports, metric, show_groups=k == len(rates) - 1, chance=chance)
            if k == 0:
                ax.set_title("Success by motion type (95% Wilson intervals)", fontsize=FONT_PT + 1, pad=4 + 9 * bar_rows)
                ax.legend(fontsize=FONT_PT - 1, ncol=min(bar_entries, 3), frameon=False, loc="lower center",
                          bbox_to_anchor=(0.5, 0.98), handlelength=1.2, columnspacing=0.8, borderaxespad=0.2)
        with open_output(path, "wb") as handle:
            figure.savefig(handle, format="png", metadata={"Software": None}, bbox_inches="tight")
    finally:
        plt.close(figure)
