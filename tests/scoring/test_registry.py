"""Metrics through their registry (scoring.registry): a toy metric registered here shows up in
every place metrics are listed, and the per-episode rows agree with the summary."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from schemas.errors import SpecError
from scoring.chance import chance_row
from scoring.cli import main
from scoring.io import load_run
from scoring.paper import PAPER_ROWS
from scoring.plot import radar_metrics, radar_values
from scoring.registry import Metric, metric_named, metric_names, register, registered, unregister
from scoring.report import score_run
from scoring.robustness import RepeatSet, robustness
from tests.scoring.rollouts import Ep, write_run
from tests.scoring.test_cli import GOOD, MISS

#: A toy mean: the acting frames an episode lasted (fewer is better); a toy rate: the palm
#: localized by acting frame 2.
FRAMES = Metric("toy_frames", "mean", "frames", lower_is_better=True,
                value=lambda per, ok: per.acting_frames.astype(np.float64), counted=lambda per, ok: ok)
EARLY = Metric("S_early", "rate", "%", event=lambda per: np.where((per.t_loc >= 0) & (per.t_loc <= 2), per.t_loc, -1),
               event_column="t_early", flag_column="early", consistency="early")


@pytest.fixture
def toys():
    register(FRAMES)
    register(EARLY)
    try:
        yield
    finally:
        unregister(FRAMES.name)
        unregister(EARLY.name)


@pytest.fixture
def run(tmp_path):
    episodes = [
        Ep(**GOOD, motion_type="linear", intercept_setting="fast"),
        Ep(**MISS, motion_type="circular", intercept_setting="slow", object="mug"),
        Ep(**GOOD, motion_type="harmonic", intercept_setting="fast", status="error"),
        Ep(**GOOD, motion_type="linear", intercept_setting="medium"),
    ]
    return write_run(tmp_path / "oracle-run", episodes, policy="oracle")


def _eval(capsys, *argv):
    code = main(["eval", *argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def test_a_toy_metric_is_listed_wherever_metrics_are(tmp_path, capsys, run, toys):
    assert metric_names()[-2:] == ("toy_frames", "S_early") and metric_named("toy_frames") is FRAMES
    summary = json.loads(_eval(capsys, str(run), "--json"))
    # acting frames 4, 3, 4 (error: not counted), 4; localized by acting frame 2 in the good ok episodes
    assert summary["metrics"]["toy_frames"] == pytest.approx(11 / 3)
    assert summary["metrics"]["S_early"] == pytest.approx(50.0)
    assert summary["intervals"]["toy_frames"] is not None and summary["intervals"]["S_early"][0] < 50.0
    assert summary["by_motion"]["linear"]["toy_frames"] == pytest.approx(4.0)
    text = _eval(capsys, str(run))
    assert "toy_frames v" in text and "S_early (%) ^" in text and "S_early 95% CI" in text and "  toy_frames  S_early (%)\n" in text
    table, md, png, rows = tmp_path / "s.csv", tmp_path / "s.md", tmp_path / "s.png", tmp_path / "e.parquet"
    _eval(capsys, str(run), "--csv", str(table), "--markdown", str(md), "--plot", str(png), "--episodes", str(rows))
    fields = next(csv.reader(io.StringIO(table.read_text())))
    assert fields[-6:] == ["toy_frames", "toy_frames_low", "toy_frames_high", "S_early", "S_early_low", "S_early_high"]
    assert fields[fields.index("Q_line_high") + 1] == "n_Q"  # the coverage of Q_smooth and Q_line
    assert "toy_frames ↓" in md.read_text() and png.read_bytes()[:4] == b"\x89PNG"
    episodes = pq.read_table(rows)
    names = episodes.column_names
    assert names.index("t_early") == names.index("t_hold") + 1
    assert names.index("early") == names.index("held") + 1 and names.index("toy_frames") == names.index("R_time") + 1
    assert episodes.column("toy_frames").to_pylist() == [4.0, 3.0, None, 4.0]
    assert episodes.column("early").to_pylist() == [True, False, False, True]
    # robustness: the toy mean's spread and the toy rate's consistency
    report = robustness(RepeatSet(run, {"policy": "oracle"}, (load_run(run), load_run(run)), ({}, {})))
    assert report["spread"]["toy_frames"] == 0.0 and report["consistency"]["early"] == {"all": 2, "none": 2, "mixed": 0}
    assert report["rates"]["S_early"] == [50.0, 50.0]
    # the radar draws both, the paper's rows have no value for them, the chance row picks the lower frames
    assert [m.name for m in radar_metrics()][-2:] == ["toy_frames", "S_early"]
    assert radar_values({"toy_frames": 3.0, "S_early": 50.0})[-2:] == [0.25, 0.5]
    assert PAPER_ROWS[0].metrics["toy_frames"] is None and PAPER_ROWS[0].metrics["S_loc"] == 100.0
    overall = score_run(load_run(run)).overall
    assert chance_row([("a", overall), ("b", overall)]).metrics["toy_frames"] == pytest.approx(11 / 3)


def test_per_episode_rows_average_to_the_summary_for_every_metric(tmp_path, capsys, run):
    path = tmp_path / "e.parquet"
    summary = json.loads(_eval(capsys, str(run), "--json", "--episodes", str(path)))["metrics"]
    rows = pq.read_table(path)
    for metric in registered():
        if metric.is_rate:
            flags = rows.column(metric.flag_column).to_pylist()
            assert 100.0 * sum(flags) / len(flags) == pytest.approx(summary[metric.name]), metric.name
        else:
            values = [v for v in rows.column(metric.name).to_pylist() if v is not None]
            expected = summary[metric.name]
            assert (sum(values) / len(values) if values else None) == pytest.approx(expected), metric.name


def test_metric_registry_refuses_bad_metrics_in_one_line():
    with pytest.raises(SpecError, match=r"unknown metric 'S_fly' \(expected one of \["):
        metric_named("S_fly")
    with pytest.raises(SpecError, match="'S_loc' is already registered"):
        register(Metric("S_loc", "mean", "", value=lambda per, ok: ok, counted=lambda per, ok: ok))
    with pytest.raises(SpecError, match="kind must be one of"):
        Metric("S_x", "median", "")
    with pytest.raises(SpecError, match="a rate needs event"):
        Metric("S_x", "rate", "%")
    with pytest.raises(SpecError, match="must be an identifier"):
        Metric("S x", "mean", "", value=lambda per, ok: ok, counted=lambda per, ok: ok)
