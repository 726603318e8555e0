"""The metrics as objects: one :class:`Metric` per score, in a registry that every table,
row, plot and reading iterates (:mod:`scoring.metrics`, :mod:`scoring.episodes`,
:mod:`scoring.robustness`, :mod:`scoring.plot`, :mod:`scoring.paper`, :mod:`scoring.report`,
:mod:`scoring.chance`).

A metric is a success *rate* (``event``: the frame its event first happens in each
episode, -1 never; an episode in error never succeeds; percent, with a Wilson interval) or
a *mean* (``value`` per episode, averaged over the episodes ``counted`` picks; a normal
interval). Both take the per-episode facts (:class:`scoring.metrics.EpisodeMetrics`) and
``ok`` (n,), the episodes not in error.

**A new metric touches two files:** its :class:`Metric` and :func:`register` call at the end
of this module, and, if it needs a per-episode fact the others do not read, that fact in
:class:`scoring.metrics.EpisodeMetrics` (:func:`scoring.metrics.episode_metrics`). Tables, JSON, CSV, the
per-episode rows, robustness spreads, the radar and the bars then list it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.errors import SpecError
from schemas.names import shorten

#: What a metric reports: a success rate (percent) or a mean over episodes.
KINDS = ("rate", "mean")


@dataclass(frozen=True)
class Metric:
    """One score. ``name`` is its column and JSON key; ``unit`` what its values are in.

    Rates: ``event(per)`` (n,) first event frame or -1; the per-episode rows hold it as
    ``event_column`` and the success as the boolean ``flag_column``; ``consistency`` names it
    in a robustness report's consistency counts ("" leaves it out of them).
    Means: ``value(per, ok)`` (n,) and ``counted(per, ok)`` (n,) bool; the rows hold the
    value where counted, else null.
    ``lower_is_better`` orders the chance row and the table's arrows; ``in_paper``: a column
    of the paper's Table 3 (its published rows carry a value); ``on_radar``: an axis of the
    plot's radar; ``headline``: listed first in every table; ``coverage``: a mean's column
    after which every table shows a column of this name, the episodes it averages.
    """

    name: str
    kind: str
    unit: str
    lower_is_better: bool = False
    event: Callable[[Any], np.ndarray] | None = None
    event_column: str = ""
    flag_column: str = ""
    consistency: str = ""
    value: Callable[[Any, np.ndarray], np.ndarray] | None = None
    counted: Callable[[Any, np.ndarray], np.ndarray] | None = None
    in_paper: bool = False
    on_radar: bool = True
    headline: bool = False
    coverage: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise SpecError(f"metric name must be an identifier, got {shorten(repr(self.name))}")
        if self.kind not in KINDS:
            raise SpecError(f"metric {self.name}: kind must be one of {KINDS}, got {shorten(repr(self.kind))}")
        if self.kind == "rate" and (self.event is None or not self.event_column or not self.flag_column):
            raise SpecError(f"metric {self.name}: a rate needs event, event_column and flag_column")
        if self.kind == "mean" and (self.value is None or self.counted is None):
            raise SpecError(f"metric {self.name}: a mean needs value and counted")
        if self.coverage and (self.kind != "mean" or not self.coverage.isidentifier()):
            raise SpecError(f"metric {self.name}: coverage must name a column of a mean, got {shorten(repr(self.coverage))}")

    @property
    def is_rate(self) -> bool:
        return self.kind == "rate"

    def success(self, per: Any, ok: np.ndarray) -> np.ndarray:
        """(n,) whether each episode succeeded (a rate): its event happened and it is ``ok``."""
        assert self.event is not None
        return (self.event(per) >= 0) & ok

    def per_episode(self, per: Any, ok: np.ndarray) -> np.ndarray:
        """(n,) a mean's value per episode, NaN where it is not counted."""
        assert self.value is not None and self.counted is not None
        return np.where(self.counted(per, ok), self.value(per, ok), np.nan)

    @property
    def radar_label(self) -> str:
        """The radar's axis label: an error is drawn as 1 / (1 + E), outward better."""
        return f"1/(1+{self.name})" if self.lower_is_better else self.name

    def radar_value(self, value: float | None) -> float:
        """``value`` mapped to [0, 1], higher better; a missing value is NaN, which the radar
        leaves out (a gap in the line), never a 0 that would read as a score."""
        if value is None:
            return float("nan")
        if self.is_rate:
            return value / 100.0
        if self.lower_is_better:
            return 1.0 / (1.0 + max(value, 0.0))
        return min(max(value, 0.0), 1.0)


_REGISTRY: dict[str, Metric] = {}


def register(metric: Metric) -> Metric:
    """Add ``metric`` after the registered ones (one per name); returns it."""
    if not isinstance(metric, Metric):
        raise SpecError(f"not a scoring.registry.Metric: {shorten(repr(metric))}")
    if metric.name in _REGISTRY:
        raise SpecError(f"a metric named {metric.name!r} is already registered")
    _REGISTRY[metric.name] = metric
    return metric


def unregister(name: str) -> None:
    """Remove the metric ``name`` (for tests that register a toy metric)."""
    _REGISTRY.pop(name, None)


def metric_named(name: str) -> Metric:
    """The registered metric ``name``; SpecError naming it and the known ones."""
    found = _REGISTRY.get(name) if isinstance(name, str) else None
    if found is None:
        raise SpecError(f"unknown metric {shorten(repr(name))} (expected one of {sorted(_REGISTRY)})")
    return found


def registered() -> tuple[Metric, ...]:
    """Every metric in registration order (the per-episode rows' and the paper's order)."""
    return tuple(_REGISTRY.values())


def table_metrics() -> tuple[Metric, ...]:
    """Every metric in the tables' order: the headline first, then registration order."""
    metrics = registered()
    return tuple(m for m in metrics if m.headline) + tuple(m for m in metrics if not m.headline)


def metric_names() -> tuple[str, ...]:
    """The names of :func:`table_metrics`."""
    return tuple(m.name for m in table_metrics())


# --- the paper's seven (Table 3's column order), then Dyana's headline -----------------


def _all(per: Any, ok: np.ndarray) -> np.ndarray:
    return np.ones(len(ok), dtype=bool)


def _measured(per: Any, ok: np.ndarray) -> np.ndarray:
    """Episodes with acting frames (an error's recorded frames still count)."""
    return per.acting_frames > 0


#: Dyana's success, the headline (S_hold since dataset 5.0.0, whose hand holds: a grasp
#: that holds the object through the hold test; S_grasp_contact before): an episode's
#: trajectory quality counts under the ``dyana`` reading only if it succeeded.
SUCCESS = "S_hold"


def success(per: Any, ok: np.ndarray) -> np.ndarray:
    """(n,) whether each episode reached :data:`SUCCESS` (and is ``ok``)."""
    return metric_named(SUCCESS).success(per, ok)


def _completed(per: Any, ok: np.ndarray) -> np.ndarray:
    """The paper's successful trajectories: localized and grasped (both of its successes)."""
    return per.localized & per.grasped & ok


def _quality_value(name: str) -> Callable[[Any, np.ndarray], np.ndarray]:
    """Q per episode: ``weighted`` (the ``dyana`` reading), Q x success, so 0 for a failure;
    ``successful``, Q itself."""
    def value(per: Any, ok: np.ndarray) -> np.ndarray:
        q = getattr(per, name)
        return np.where(success(per, ok), q, 0.0) if per.quality == "weighted" else q
    return value


def _quality_counted(per: Any, ok: np.ndarray) -> np.ndarray:
    """``weighted``: every episode; ``successful``: the successful trajectories only."""
    return _all(per, ok) if per.quality == "weighted" else _completed(per, ok)


register(Metric("S_loc", "rate", "%", event=lambda per: per.t_loc, event_column="t_loc", flag_column="localized",
                consistency="localization", in_paper=True))
register(Metric("E_loc", "mean", "units", lower_is_better=True, value=lambda per, ok: per.e_loc, counted=_measured,
                in_paper=True))
register(Metric("S_gra", "rate", "%", event=lambda per: per.t_gra, event_column="t_gra", flag_column="grasped",
                in_paper=True))
register(Metric("E_gra", "mean", "units", lower_is_better=True, value=lambda per, ok: per.e_gra, counted=_measured,
                in_paper=True))
register(Metric("Q_smooth", "mean", "", value=_quality_value("q_smooth"), counted=_quality_counted, in_paper=True))
register(Metric("Q_line", "mean", "", value=_quality_value("q_line"), counted=_quality_counted, in_paper=True,
                coverage="n_Q"))
# An episode in error scores 0.
register(Metric("R_time", "mean", "", value=lambda per, ok: np.where(ok, per.r_time, 0.0), counted=_all,
                in_paper=True))


def _held(per: Any) -> np.ndarray:
    if per.t_hold is None:
        raise SpecError("S_hold needs the hold test: score with scoring.hold.run_metrics")
    return per.t_hold


register(Metric("S_grasp_contact", "rate", "%", event=lambda per: per.t_contact, event_column="t_grasp_contact",
                flag_column="grasp_contact", consistency="grasp_contact", on_radar=False))
# The grasp that holds (docs/reference/metrics.md, S_hold), the headline: the hold test from the closing frame.
register(Metric("S_hold", "rate", "%", event=_held, event_column="t_hold", flag_column="held", consistency="hold",
                on_radar=False, headline=True))
