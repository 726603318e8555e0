"""The chance row: the best score blind play reaches, per metric (``scoring eval --chance RUN ...``).

Given runs of blind reference policies (``pipeline eval --policy blind-centre`` etc.,
:mod:`pipeline.policies.blind`) on the same episodes as the scored runs, the chance row
holds, for each metric, the best value any of them reached: the highest success rate,
Q and R_time, the lowest error. A model's score at or below it does not show that the
model sees. Runs on other episodes are refused: a chance level is only one on the same
episodes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from schemas.errors import DyanaError
from schemas.names import shorten
from scoring.metrics import Summary
from scoring.registry import table_metrics

CHANCE_LABEL = "chance (best blind)"


@dataclass(frozen=True)
class ChanceRow:
    """Per metric, the best blind value (None if no blind run has one) and the label of
    the run that reached it; ``runs`` the blind runs' labels, ``episodes`` their episode count;
    ``by_motion`` the same best values within each motion type (what the plot's bars mark);
    ``averaged_over`` each best mean's coverage (the episodes it averages in that run)."""

    runs: tuple[str, ...]
    episodes: int
    metrics: dict[str, float | None]
    best_of: dict[str, str | None]
    by_motion: dict[str, dict[str, float | None]] = field(default_factory=dict)
    averaged_over: dict[str, int | None] = field(default_factory=dict)

    def as_dict(self) -> dict[str, object]:
        return {"label": CHANCE_LABEL, "runs": list(self.runs), "episodes": self.episodes,
                "metrics": dict(self.metrics), "best_of": dict(self.best_of),
                "averaged_over": dict(self.averaged_over),
                "by_motion": {group: dict(metrics) for group, metrics in self.by_motion.items()}}


def chance_row(runs: Sequence[tuple[str, Summary]]) -> ChanceRow:
    """The best value per metric over ``(label, overall summary)`` of the blind runs."""
    if not runs:
        raise ValueError("a chance row needs at least one blind run")
    metrics: dict[str, float | None] = {}
    best_of: dict[str, str | None] = {}
    averaged_over: dict[str, int | None] = {}
    for metric in table_metrics():
        name = metric.name
        given = [(value, label, s) for label, s in runs if (value := s.metrics[name]) is not None]
        if not metric.is_rate:
            averaged_over[name] = None
        if not given:
            metrics[name] = best_of[name] = None
            continue
        pick = min if metric.lower_is_better else max
        value, label, best = pick(given, key=lambda entry: entry[0])
        metrics[name], best_of[name] = value, label
        if not metric.is_rate:
            averaged_over[name] = best.averaged_over.get(name)
    return ChanceRow(tuple(label for label, _ in runs), runs[0][1].episodes, metrics, best_of, {}, averaged_over)


def chance_by_group(runs: Sequence[tuple[str, Mapping[str, Summary]]]) -> dict[str, dict[str, float | None]]:
    """Per group of a breakdown (``(label, {group: summary})`` of each blind run), the best
    value per metric over the runs that hold episodes of that group."""
    groups: list[str] = []
    for _, by_group in runs:
        groups += [g for g in by_group if g not in groups]
    out: dict[str, dict[str, float | None]] = {}
    for group in groups:
        held = [(label, by_group[group]) for label, by_group in runs if group in by_group and by_group[group].episodes]
        if held:
            out[group] = chance_row(held).metrics
    return out


def check_same_episodes(blind: Sequence[tuple[str, np.ndarray]], scored: Sequence[tuple[str, np.ndarray]]) -> None:
    """DyanaError naming the first run whose episodes (ids, in index order) differ from the
    first blind run's: chance rows compare runs on the same episodes only."""
    if not blind:
        return
    name, ids = blind[0]
    reference = list(ids)
    for other, other_ids in list(blind[1:]) + list(scored):
        if list(other_ids) != reference:
            raise DyanaError(
                f"--chance {shorten(name)}: holds other episodes than {shorten(other)} "
                f"({len(reference)} vs {len(other_ids)} episodes, or other ids): run the blind policies "
                "on the same slice and episodes"
            )
