"""The per-episode rows (``scoring eval --episodes``) average to the summaries, under every
status (policy error, time-out, no acting frame, obstacle contact), every reading and both
``--obstacle-contact`` modes, on every kind of slice (table motions, projectile, obstacle,
irregular, and the held-out test slices)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pyarrow.csv as pa_csv
import pytest

from generators.recipe import spec_for
from pipeline.stages.episode import episode
from schemas.frames import EpisodeFrames
from scoring.episodes import run_episodes, write_episodes
from scoring.io import from_recordings
from scoring.metrics import READINGS
from scoring.registry import registered
from scoring.report import BREAKDOWNS, CONTACT_MODES, score_run

#: One slice of each kind; test-1k and test-complex are the held-out ones.
SLICES = ("linear-medium", "projectile-fast", "obstacle-medium", "irregular-slow", "test-1k", "test-complex")
PER_FRAME = tuple(f.name for f in dataclasses.fields(EpisodeFrames) if f.name != "grasp_angles")


def _cut(frames: EpisodeFrames, keep: int) -> EpisodeFrames:
    """The first ``keep`` frames of an episode (a run that stopped early)."""
    return dataclasses.replace(frames, **{name: getattr(frames, name)[:keep] for name in PER_FRAME
                                          if getattr(frames, name) is not None})


def _run(slice_name: str):
    """Six rollouts of the slice: the ground truth's path (a success); the same path 3 units
    off in X (the hand still closes: grasped, never localized); a policy error and a time-out
    with the ground truth's frames (failures whatever the frames show); a time-out that
    stopped before its first acting frame; and, where the slice has obstacles, the first
    of the first two episodes with obstacles touching one at its last acting frame."""
    specs = [spec_for(slice_name, i) for i in range(6)]
    truth = [episode(s) for s in specs]
    recordings = list(truth)
    palm = truth[1].palm_pose.copy()
    palm[:, 0] += 3.0
    recordings[1] = dataclasses.replace(truth[1], palm_pose=palm)
    recordings[4] = _cut(truth[4], specs[4].observe_frames)
    touched = next((i for i in (0, 1) if truth[i].obstacle_clearance is not None), None)
    if touched is not None:
        clearance = truth[touched].obstacle_clearance.copy()
        clearance[-1] = -0.05
        recordings[touched] = dataclasses.replace(recordings[touched], obstacle_clearance=clearance)
    errors = [None, None, "policy_error: the policy raised ValueError", "timeout: no action within 30 s",
              "timeout: no action within 30 s", None]
    return from_recordings("run", slice_name, specs, recordings, policy="some-policy", errors=errors)


def _column_means(rows: list[dict]) -> dict[str, float | None]:
    """Each metric from its per-episode column: a rate's flag as a percentage, a mean's values
    averaged over the rows that hold one."""
    out: dict[str, float | None] = {}
    for metric in registered():
        if metric.is_rate:
            out[metric.name] = 100.0 * sum(bool(r[metric.flag_column]) for r in rows) / len(rows) if rows else None
        else:
            values = [r[metric.name] for r in rows if r[metric.name] is not None]
            out[metric.name] = sum(values) / len(values) if values else None
    return out


def _assert_equal(summary, rows, where: str) -> None:
    expected = _column_means(rows)
    for name, value in summary.metrics.items():
        assert (value is None) == (expected[name] is None), (where, name, value, expected[name])
        if value is not None:
            assert expected[name] == pytest.approx(value, rel=1e-12, abs=1e-12), (where, name)
    for name, count in summary.averaged_over.items():
        assert count == sum(r[name] is not None for r in rows), (where, name)


@pytest.mark.parametrize("slice_name", SLICES)
def test_the_rows_average_to_the_summary_on_every_slice_kind(slice_name):
    data = _run(slice_name)
    assert data.error.tolist() == [False, False, True, True, True, False]
    for reading in READINGS:
        for contact in CONTACT_MODES:
            report = score_run(data, reading=reading, obstacle_contact=contact)
            rows = run_episodes(report).to_pylist()
            where = f"{slice_name}, {reading}, {contact}"
            _assert_equal(report.overall, rows, where)
            for key, attribute, *_ in BREAKDOWNS:
                for group, summary in report.breakdowns[key].items():
                    _assert_equal(summary, [r for r in rows if r[attribute] == group], f"{where}, {group}")
    fail = run_episodes(score_run(data)).to_pylist()
    assert fail[0]["grasp_contact"] == (not fail[0]["obstacle_contact"])  # contact fails it by default
    assert fail[1]["grasped"] == (not fail[1]["obstacle_contact"]) and not fail[1]["localized"]
    assert any(r["obstacle_contact"] for r in fail) == (slice_name in ("obstacle-medium", "test-complex"))
    assert not any(r["grasped"] or r["localized"] for r in fail[2:5])  # errors and time-outs
    assert fail[4]["acting_frames"] == 0 and fail[4]["E_loc"] is None


def test_an_obstacle_contact_is_a_failure_in_the_rows_written_as_csv(tmp_path):
    """The case found from outside: rows that said ``grasped`` beside ``obstacle_contact``."""
    data = _run("obstacle-medium")
    path = tmp_path / "rows.csv"
    write_episodes([score_run(data)], path)
    rows = pa_csv.read_csv(path).to_pylist()
    touched = [r for r in rows if r["obstacle_contact"]]
    assert touched and not any(r["grasped"] or r["localized"] or r["grasp_contact"] for r in touched)
    assert all(r["R_time"] == 0.0 and r["Q_smooth"] == 0.0 for r in touched)
    reported = run_episodes(score_run(data, obstacle_contact="report")).to_pylist()
    assert reported[0]["obstacle_contact"] and reported[0]["grasp_contact"]  # 'report' only counts it
    assert np.isclose(100.0 * np.mean([r["grasped"] for r in rows]), score_run(data).overall.metrics["S_gra"])


def test_robustness_rates_are_the_repeats_summary_rates():
    """A repeats report's per-repeat success rates apply the same failures (obstacle contact)."""
    from pathlib import Path

    from scoring.robustness import RepeatSet, robustness

    data = _run("obstacle-medium")
    repeats = RepeatSet(Path("repeats"), {"policy": "some-policy"}, (data, data), ({}, {}))
    for contact in CONTACT_MODES:
        summary = score_run(data, obstacle_contact=contact).overall.metrics
        report = robustness(repeats, contact_fails=contact == "fail")
        for name, rates in report["rates"].items():
            assert rates == [pytest.approx(summary[name])] * 2, (contact, name)
