"""One PNG comparing runs: a radar over the seven metrics in the style of the
paper's Figure 1 (every axis normalised to [0, 1], outward is better), and bars of
the success rates per motion type with their Wilson intervals."""

from __future__ import annotations

import os
from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from catalog.atomic import atomic_open  # noqa: E402
from scoring.metrics import METRIC_NAMES, SUCCESS_RATE_NAMES  # noqa: E402
from scoring.report import RunReport  # noqa: E402

#: Axis labels of the radar; errors are shown as 1 / (1 + E) so that outward is better.
RADAR_LABELS = {
    "S_loc": "S_loc / 100",
    "E_loc": "1 / (1 + E_loc)",
    "S_gra": "S_gra / 100",
    "E_gra": "1 / (1 + E_gra)",
    "Q_smooth": "Q_smooth",
    "Q_line": "max(Q_line, 0)",
    "R_time": "R_time",
    "S_grasp_contact": "S_grasp_contact / 100",
}


def radar_values(metrics: dict[str, float | None]) -> list[float]:
    """The seven metrics mapped to [0, 1], higher better; a missing metric plots as 0."""
    out = []
    for name in METRIC_NAMES:
        value = metrics[name]
        if value is None:
            out.append(0.0)
        elif name in SUCCESS_RATE_NAMES:
            out.append(value / 100.0)
        elif name in ("E_loc", "E_gra"):
            out.append(1.0 / (1.0 + max(value, 0.0)))
        else:
            out.append(min(max(value, 0.0), 1.0))
    return out


def _radar(ax, reports: Sequence[RunReport], colours) -> None:
    angles = np.linspace(0.0, 2.0 * np.pi, len(METRIC_NAMES), endpoint=False)
    closed = np.concatenate([angles, angles[:1]])
    for report, colour in zip(reports, colours):
        values = radar_values(report.overall.metrics)
        ax.plot(closed, values + values[:1], color=colour, linewidth=1.5, label=report.label)
        ax.fill(closed, values + values[:1], color=colour, alpha=0.12)
    ax.set_theta_offset(np.pi / 2.0)
    ax.set_theta_direction(-1)
    ax.set_xticks(angles)
    ax.set_xticklabels([RADAR_LABELS[n] for n in METRIC_NAMES], fontsize=8)
    ax.tick_params(axis="x", pad=6)
    ax.set_ylim(0.0, 1.0)
    ax.set_yticks([0.25, 0.5, 0.75, 1.0])
    ax.set_yticklabels(["0.25", "0.5", "0.75", "1"], fontsize=6, color="grey")
    ax.set_rlabel_position(180.0 / len(METRIC_NAMES))
    ax.set_title("All metrics (outward is better)", fontsize=10, pad=22)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), fontsize=8, ncol=min(len(reports), 3), frameon=False)


def _bars(ax, reports: Sequence[RunReport], colours, metric: str) -> None:
    groups = list(reports[0].breakdowns["by_motion"])
    for report in reports[1:]:
        groups += [g for g in report.breakdowns["by_motion"] if g not in groups]
    x = np.arange(len(groups))
    width = 0.8 / len(reports)
    for i, (report, colour) in enumerate(zip(reports, colours)):
        heights, low, high = [], [], []
        for group in groups:
            summary = report.breakdowns["by_motion"].get(group)
            value = None if summary is None else summary.metrics[metric]
            interval = None if summary is None else summary.intervals[metric]
            heights.append(0.0 if value is None else value)
            # Wilson bounds at 0% or 100% equal the rate up to rounding: clamp the bars at 0.
            low.append(0.0 if interval is None or value is None else max(value - interval[0], 0.0))
            high.append(0.0 if interval is None or value is None else max(interval[1] - value, 0.0))
        ax.bar(x - 0.4 + width * (i + 0.5), heights, width, yerr=[low, high], color=colour, capsize=2,
               label=report.label, error_kw={"linewidth": 0.8})
    ax.set_xticks(x)
    ax.set_xticklabels(groups)
    ax.set_ylim(0.0, 105.0)
    ax.set_ylabel(f"{metric} (%)")
    ax.set_title(f"{metric} by motion type (95% Wilson)", fontsize=10)
    ax.grid(axis="y", linewidth=0.3)


def plot_runs(reports: Sequence[RunReport], path: str | os.PathLike[str]) -> None:
    """Write the radar and the per-motion success bars of ``reports`` to a PNG (atomically)."""
    if not reports:
        raise ValueError("nothing to plot: no runs")
    colours = [plt.get_cmap("tab10")(i % 10) for i in range(len(reports))]
    figure = plt.figure(figsize=(13.0, 4.8), dpi=100)
    try:
        grid = figure.add_gridspec(1, 3, width_ratios=[1.25, 1.0, 1.0], wspace=0.45)
        _radar(figure.add_subplot(grid[0, 0], projection="polar"), reports, colours)
        _bars(figure.add_subplot(grid[0, 1]), reports, colours, "S_loc")
        _bars(figure.add_subplot(grid[0, 2]), reports, colours, "S_gra")
        with atomic_open(path, "wb") as handle:
            figure.savefig(handle, format="png", metadata={"Software": None}, bbox_inches="tight")
    finally:
        plt.close(figure)
