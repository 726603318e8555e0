"""One row per scored episode: ``scoring eval RUN ... --episodes FILE.parquet|.csv``.

The summaries say how a policy did; this table says where, so a failure can be found
and opened (``pipeline view RUN --episode N``). Statuses are applied as in
:func:`scoring.metrics.aggregate` (the same :func:`scoring.metrics.failed`): an episode
that ended in error (a policy error, a time-out), or whose hand touched an obstacle under
``--obstacle-contact fail``, is neither localized nor grasped, has R_time 0 and its Q as
the reading scores a failure, whatever its frames show. So each metric's column averages
(a rate: its flag's percentage) to the summary's value.

Columns (:func:`episode_fields`): the run (label, folder, slice, policy); the episode
(index, id, motion type, interception setting, object, hand, rollout format); its
``status`` (``ok``/``error``) and ``error`` message; ``acting_frames``; the event
frames ``t_loc``, ``t_gra``, ``t_grasp_contact`` (counted from the first acting frame,
null when the event never happened); the three successes as booleans; ``E_loc``,
``E_gra`` (null without acting frames), ``Q_smooth``, ``Q_line`` (``dyana`` reading: Q x
success, 0 for a failure; ``paper``/``lenient``: null unless a successful trajectory)
and ``R_time`` (one column each per metric of :mod:`scoring.registry`);
``min_obstacle_clearance`` and ``obstacle_contact`` (null without
obstacles); the episode's ``failure`` class (:mod:`scoring.taxonomy`) and its evidence:
``palm_displacement`` (the palm's largest distance from its first acting position),
``path_miss`` (its closest approach to where the object was up to 10 frames before or
after) and ``crossing_offset`` (the smallest shift in frames that puts the palm within the
localization tolerance of the object: negative, the palm was late; positive, early; 0,
localized; null if none within 10 frames does); ``disturbance_time_s`` (when the motion
changed, in a ``--disturb`` run; null otherwise).
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from catalog.store.outputs import open_output
from schemas.errors import DyanaError
from schemas.names import shorten
from schemas.obstacles import CONTACT_CLEARANCE
from scoring.metrics import failed
from scoring.registry import registered
from scoring.report import RunReport

#: The columns before and after the metrics' (:func:`episode_fields`).
_RUN_FIELDS = [
    pa.field("label", pa.string()),
    pa.field("run", pa.string()),
    pa.field("slice", pa.string()),
    pa.field("policy", pa.string()),
    pa.field("episode_index", pa.int64()),
    pa.field("episode_id", pa.string()),
    pa.field("motion_type", pa.string()),
    pa.field("intercept_setting", pa.string()),
    pa.field("object", pa.string()),
    pa.field("hand", pa.string()),
    pa.field("rollout_format", pa.string()),
    pa.field("status", pa.string()),
    pa.field("error", pa.string()),
    pa.field("acting_frames", pa.int64()),
]
_AFTER_FIELDS = [
    pa.field("min_obstacle_clearance", pa.float64()),
    pa.field("obstacle_contact", pa.bool_()),
    pa.field("failure", pa.string()),
    pa.field("palm_displacement", pa.float64()),
    pa.field("path_miss", pa.float64()),
    pa.field("crossing_offset", pa.int64()),
    pa.field("disturbance_time_s", pa.float64()),
]


def episode_fields() -> list[pa.Field]:
    """The table's columns: the run's and episode's, then per registered metric
    (:mod:`scoring.registry`, registration order) each rate's event frame, each rate's
    success flag, each mean's value, then obstacles, failure class and its evidence."""
    metrics = registered()
    return (
        _RUN_FIELDS
        + [pa.field(m.event_column, pa.int64()) for m in metrics if m.is_rate]
        + [pa.field(m.flag_column, pa.bool_()) for m in metrics if m.is_rate]
        + [pa.field(m.name, pa.float64()) for m in metrics if not m.is_rate]
        + _AFTER_FIELDS
    )


FORMATS = (".parquet", ".csv")


def _event(frames: np.ndarray) -> pa.Array:
    return pa.array(np.where(frames >= 0, frames, 0), pa.int64(), mask=frames < 0)


def _measure(values: np.ndarray) -> pa.Array:
    values = np.asarray(values, dtype=np.float64)
    return pa.array(np.nan_to_num(values), pa.float64(), mask=np.isnan(values))


def run_episodes(report: RunReport) -> pa.Table:
    """The per-episode rows of one scored run."""
    data, per, failures = report.data, report.per_episode, report.failures
    n = data.episodes
    ok = ~failed(data.error, data.min_clearance, report.obstacle_contact == "fail")
    rates = [m for m in registered() if m.is_rate]
    means = [m for m in registered() if not m.is_rate]
    columns = {
        "label": pa.array([report.label] * n, pa.string()),
        "run": pa.array([report.name] * n, pa.string()),
        "slice": pa.array([report.slice] * n, pa.string()),
        "policy": pa.array([report.policy] * n, pa.string()),
        "episode_index": pa.array(data.episode_index, pa.int64()),
        "episode_id": pa.array(data.episode_id.tolist(), pa.string()),
        "motion_type": pa.array(data.motion_type.tolist(), pa.string()),
        "intercept_setting": pa.array(data.intercept_setting.tolist(), pa.string()),
        "object": pa.array(data.object.tolist(), pa.string()),
        "hand": pa.array(data.hand.tolist(), pa.string()),
        "rollout_format": pa.array(data.rollout_format.tolist(), pa.string()),
        "status": pa.array(np.where(data.error, "error", "ok").tolist(), pa.string()),
        "error": pa.array(data.error_message.tolist(), pa.string()),
        "acting_frames": pa.array(per.acting_frames, pa.int64()),
        **{m.event_column: _event(m.event(per)) for m in rates if m.event is not None},
        **{m.flag_column: pa.array(m.success(per, ok), pa.bool_()) for m in rates},
        **{m.name: _measure(m.per_episode(per, ok)) for m in means},
        **_obstacle_columns(data.min_clearance, n),
        "failure": pa.array(failures.failure.tolist(), pa.string()),
        "palm_displacement": _measure(failures.displacement),
        "path_miss": _measure(failures.path_miss),
        "crossing_offset": pa.array(failures.crossing_offset, pa.int64(), mask=~failures.crossed),
        "disturbance_time_s": _measure(np.full(n, np.nan) if data.disturbance_time_s is None else data.disturbance_time_s),
    }
    return pa.table(columns, schema=pa.schema(episode_fields()))


def _obstacle_columns(min_clearance: np.ndarray | None, n: int) -> dict[str, pa.Array]:
    """Smallest hand-obstacle clearance over the acting frames and whether the hand touched
    an obstacle; null for an episode without obstacles."""
    clearance = np.full(n, np.inf) if min_clearance is None else np.asarray(min_clearance, dtype=np.float64)
    none = ~np.isfinite(clearance)
    return {
        "min_obstacle_clearance": pa.array(np.where(none, 0.0, clearance), pa.float64(), mask=none),
        "obstacle_contact": pa.array(clearance <= CONTACT_CLEARANCE, pa.bool_(), mask=none),
    }


def episodes_table(reports: Sequence[RunReport]) -> pa.Table:
    """Every run's per-episode rows, runs in the order given, episodes by index."""
    return pa.concat_tables([run_episodes(r) for r in reports])


def check_episodes_path(path: str | os.PathLike[str]) -> str:
    """The table format a path asks for (its suffix), or a one-line error before any work."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise DyanaError(f"--episodes {shorten(repr(os.fspath(path)))}: the file must end in .parquet or .csv")
    return suffix


def write_episodes(reports: Sequence[RunReport], path: str | os.PathLike[str]) -> None:
    """Write the per-episode table as Parquet or CSV (chosen by the file's suffix), atomically."""
    suffix = check_episodes_path(path)
    table = episodes_table(reports)
    try:
        with open_output(path, "wb") as handle:
            if suffix == ".parquet":
                pq.write_table(table, handle, compression="zstd")
            else:
                buffer = io.BytesIO()
                pa_csv.write_csv(table, buffer)
                handle.write(buffer.getvalue())
    except OSError as exc:
        raise DyanaError(f"{shorten(os.fspath(path))}: cannot write: {exc.strerror or exc}") from None
