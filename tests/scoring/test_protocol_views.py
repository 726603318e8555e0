"""Scoring views of the evaluation protocols: robustness across repeats, labels that say
under which protocol a score was obtained, the latency plot, disturbance times."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.jobs.evaluate import evaluate
from pipeline.jobs.repeats import evaluate_repeats
from pipeline.loop.conditions import EvalProtocol
from pipeline.loop.perturb import Perturbation
from scoring.io import load_run
from scoring.report import default_label
from scoring.robustness import load_repeats, robustness
from tests.console import run_here

BIN = Path(sys.executable).parent
OPTIONS = {"episodes": 3, "resolution": 48, "workers": 0, "progress": False, "summary": False}


def scoring(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "scoring"), "eval", *map(str, args)], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("protocols")
    evaluate_repeats("predictive", "test-1k", root / "robust", 2, EvalProtocol(perturb=Perturbation("noise", 4)), **OPTIONS)
    for n in (0, 3):
        evaluate("predictive", "test-1k", root / f"latency-{n}", protocol=EvalProtocol(latency_frames=n), **OPTIONS)
    evaluate("predictive", "test-1k", root / "disturbed", protocol=EvalProtocol(disturb=True), **OPTIONS)
    return root


def test_robustness_counts_every_episode_once_and_measures_divergence(runs, capsys):
    report = robustness(load_repeats(runs / "robust"))
    assert report["repeats"] == 2 and report["episodes"] == 3
    for event in ("localization", "grasp_contact"):
        assert sum(report["consistency"][event].values()) == 3
    assert report["action_divergence"] > 0.0  # noise changed what the policy saw, so what it did
    assert sum(g["episodes"] for g in report["by_motion"].values()) == 3
    result = run_here(capsys, "scoring", "eval", runs / "robust", "--json")
    assert result.returncode == 0, result.stderr
    payload = json.loads(result.stdout)
    assert [r["label"] for r in payload["runs"]] == ["predictive [noise:4 r0]", "predictive [noise:4 r1]"]
    assert payload["robustness"][0]["consistency"] == report["consistency"]
    assert "Robustness of predictive" in run_here(capsys, "scoring", "eval", runs / "robust").stdout


def test_an_edited_repeat_is_refused(runs, tmp_path):
    import shutil

    copy = tmp_path / "robust"
    shutil.copytree(runs / "robust", copy)
    index = json.loads((copy / "repeats.json").read_text())
    index["runs"][1]["hash"] = "0" * 64
    (copy / "repeats.json").write_text(json.dumps(index))
    result = scoring(copy)
    assert result.returncode == 2 and "manifest hash does not match" in result.stderr
    assert result.stderr.count("\n") == 1


def test_labels_say_the_protocol(runs):
    assert default_label(load_run(runs / "latency-3")) == "predictive [latency 3]"
    assert default_label(load_run(runs / "latency-0")) == "predictive"
    assert default_label(load_run(runs / "disturbed")) == "predictive [disturbed]"


def test_latency_plot_and_disturbance_times(runs, tmp_path, capsys):
    plot = tmp_path / "latency.png"
    result = run_here(capsys, "scoring", "eval", runs / "latency-0", runs / "latency-3", "--latency-plot", plot)
    assert result.returncode == 0, result.stderr
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = tmp_path / "rows.csv"
    assert run_here(capsys, "scoring", "eval", runs / "disturbed", "--episodes", rows).returncode == 0
    times = [row["disturbance_time_s"] for row in csv.DictReader(rows.open())]
    assert len(times) == 3 and all(float(t) > 0.0 for t in times if t)
    assert any(times)
