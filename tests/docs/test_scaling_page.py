"""The benchmarks page's scaling section comes from benchmarks/results/scaling.json alone (and
the site builds without it); benchmarks/scaling.py's projection is the model it states, and
the script runs end to end on a tiny configuration."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys

import pytest

from tests.docs.pages import ROOT

sys.path.insert(0, str(ROOT / "docs" / "hooks"))
import results_pages  # noqa: E402  (docs/hooks is no package: the hook modules are found by path)

RECORD = {
    "date_utc": "2026-11-27 01:00", "commit": "0123456789abcdef0123456789abcdef01234567", "cores": 2,
    "load_average_start": [0.12, 0.2, 0.3], "slice": "circular-medium", "episodes": 64, "shard_size": 8,
    "tiny_shards": 16, "resolution": 224, "tiny": False,
    "runs": {"workers_1": {"frames": 4466}},
    "measured": {"cpu_s_per_frame": 0.0125, "wall_s_per_frame_in_process": 0.013, "fps_1_worker": 70.25,
                 "fps_2_workers": 131.5, "parallel_efficiency": 0.936, "cluster_start_s": 2.5,
                 "scheduler_s_per_shard": 0.0042, "upload_s_per_shard": 0.031},
    "target": {"slice": "dyana-12m", "episodes": 184718, "frames": 12000000, "shards": 1447, "shard_size": 128},
    "projection": {"model": "T(P) = ...", "hours": {"8": 5.5, "32": 1.375, "128": 0.34375}},
    "load_average_end": [0.5, 0.4, 0.35],
}


def _scaling_module():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    spec = importlib.util.spec_from_file_location("dyana_scaling", ROOT / "benchmarks" / "scaling.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_section_shows_the_file_figures_and_loads(tmp_path):
    (tmp_path / "benchmarks" / "results").mkdir(parents=True)
    (tmp_path / "benchmarks" / "results" / "scaling.json").write_text(json.dumps(RECORD))
    text = "\n".join(results_pages.scaling_section(tmp_path, "results/files"))
    assert text.startswith("## Scaling and a projection of dyana-12m\n")
    for needle in ("| 1 local worker | 70.2 frames/s |", "| 2 local workers | 131.5 frames/s |",
                   "| parallel efficiency at 2 workers | 0.94 |", "| CPU per frame, in process | 12.5 ms |",
                   "| scheduler, per shard | 4.2 ms |", "| upload to S3 on loopback (moto), per shard | 31.0 ms |",
                   "| cluster start-up and shut-down | 2.50 s |", "12,000,000 frames, 1,447 shards of 128",
                   "| 8 | 5.5 h |", "| 32 | 1.4 h |", "| 128 | 0.3 h |", "0.12", "0.35", "commit 0123456",
                   "64 episodes of `circular-medium` at 224 px in shards of 8 (4,466 frames)"):
        assert needle in text, needle
    assert "--tiny" not in text
    (tmp_path / "benchmarks" / "results" / "scaling.json").write_text(json.dumps({**RECORD, "tiny": True}))
    assert "A `--tiny` check run: its numbers mean nothing." in "\n".join(results_pages.scaling_section(tmp_path, "f"))


def test_without_the_file_the_page_says_how_to_measure(tmp_path):
    (tmp_path / "benchmarks").mkdir()
    page = results_pages.benchmarks_page(tmp_path)
    assert "## Scaling and a projection of dyana-12m" in page
    assert "Not measured yet: run `python benchmarks/scaling.py` on a quiet machine" in page


def test_the_projection_is_the_stated_model():
    scaling = _scaling_module()
    measured = RECORD["measured"]
    hours = {p: scaling.projection(measured, 12_000_000, 1447, p) / 3600 for p in (8, 32, 128)}
    work = 12_000_000 * 0.0125 + 1447 * (0.0042 + 0.031)
    for cores, value in hours.items():
        assert value == pytest.approx((2.5 + work / (cores * 0.936)) / 3600)
    assert hours[8] > hours[32] > hours[128]
    assert scaling.projection({**measured, "upload_s_per_shard": None}, 100, 10, 1) == pytest.approx(
        2.5 + (100 * 0.0125 + 10 * 0.0042) / 0.936)
    with pytest.raises(ValueError, match="cores must be >= 1"):
        scaling.projection(measured, 1, 1, 0)


@pytest.mark.slow(cover="tests/docs/test_scaling_page.py::test_the_section_shows_the_file_figures_and_loads")
def test_the_script_runs_on_a_tiny_configuration(tmp_path):
    """Real builds (in process, 1 and 2 workers, a running cluster, moto S3) of 4 episodes at
    64 px: the file has every figure the page reads, and the page renders it."""
    out = tmp_path / "benchmarks" / "results" / "scaling.json"
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "scaling.py"), "--tiny", "--quiet", "--out", str(out)],
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    record = json.loads(out.read_text())
    assert json.loads(done.stdout.splitlines()[-1]) == record
    assert record["tiny"] is True and record["runs"]["workers_1"]["frames"] == record["runs"]["workers_2"]["frames"] > 0
    assert set(record["projection"]["hours"]) == {"2", "8", "32", "128"}
    assert record["target"]["episodes"] == 184_718
    assert len(record["load_average_start"]) == len(record["load_average_end"]) == 3
    assert "| 128 |" in "\n".join(results_pages.scaling_section(tmp_path, "f"))
