"""What each frame of delay costs: S_loc (with its Wilson interval) and E_loc against the
runs' ``--latency-frames``, one line per policy, drawn for a paper's column (3.5 in wide,
7 pt, 300 dpi). Runs in real-time mode are left out (their latency varies per call)."""

from __future__ import annotations

import os
from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402

from catalog.store.outputs import open_output  # noqa: E402
from scoring.plot import COLOURS, COLUMN_WIDTH_IN, FONT_PT, MARKERS, STYLES  # noqa: E402
from scoring.report import RunReport  # noqa: E402


def latency_points(reports: Sequence[RunReport]) -> dict[str, list[tuple[int, RunReport]]]:
    """Policy label -> [(latency frames, report)] sorted by latency, for deterministic
    rollouts (a plain run counts as latency 0)."""
    out: dict[str, list[tuple[int, RunReport]]] = {}
    for report in reports:
        if report.data.ground_truth:
            continue
        protocol = report.data.protocol or {}
        if protocol.get("realtime"):
            continue
        key = report.data.policy or report.label
        out.setdefault(key, []).append((int(protocol.get("latency_frames", 0)), report))
    return {k: sorted(v, key=lambda p: p[0]) for k, v in out.items()}


def plot_latency(reports: Sequence[RunReport], path: str | os.PathLike[str]) -> None:
    """Write the S_loc / E_loc vs latency figure (PNG) for the runs given."""
    series = latency_points(reports)
    with plt.rc_context({"font.size": FONT_PT, "axes.titlesize": FONT_PT, "legend.fontsize": FONT_PT - 1}):
        figure, (left, right) = plt.subplots(1, 2, figsize=(COLUMN_WIDTH_IN, 1.6), dpi=300)
        for k, (policy, points) in enumerate(series.items()):
            xs = [n for n, _ in points]
            rates = [r.overall.metrics["S_loc"] or 0.0 for _, r in points]
            low = [rate - (r.overall.intervals["S_loc"] or (rate, rate))[0] for rate, (_, r) in zip(rates, points)]
            high = [(r.overall.intervals["S_loc"] or (rate, rate))[1] - rate for rate, (_, r) in zip(rates, points)]
            errors = [r.overall.metrics["E_loc"] for _, r in points]
            style = {"color": COLOURS[k % len(COLOURS)], "linestyle": STYLES[k % len(STYLES)],
                     "marker": MARKERS[k % len(MARKERS)], "markersize": 3, "linewidth": 1.0}
            left.errorbar(xs, rates, yerr=[low, high], capsize=1.5, label=policy, **style)
            right.plot(xs, [e if e is not None else float("nan") for e in errors], **style)
        left.set(xlabel="latency (frames of 50 ms)", ylabel="S_loc (%)", ylim=(0, 102))
        right.set(xlabel="latency (frames of 50 ms)", ylabel="E_loc (units)")
        ticks = sorted({n for points in series.values() for n, _ in points})
        for ax in (left, right):
            ax.grid(alpha=0.3, linewidth=0.4)
            ax.set_xticks(ticks)
        left.legend(frameon=False, loc="lower left")
        figure.tight_layout(pad=0.3)
        with open_output(path, "wb") as handle:
            figure.savefig(handle, format="png", metadata={"Software": None})
        plt.close(figure)
