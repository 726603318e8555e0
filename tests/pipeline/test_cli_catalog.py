import json
import subprocess
import sys
from importlib.metadata import entry_points

import pytest

from generators.recipe import slice_summary, spec_for
from pipeline.cli_catalog import main
from schemas.slices import ATOMIC_SLICES, SLICES
from schemas.spec import EpisodeSpec, read_specs_jsonl


def run(*args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "pipeline.cli_catalog", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


def test_console_script_points_here():
    (script,) = [e for e in entry_points(group="console_scripts") if e.name == "catalog"]
    assert script.value == "pipeline.cli_catalog:main"


@pytest.mark.parametrize(
    "args, needle",
    [
        (("stats", "linear-sloww", "--json"), "unknown slice 'linear-sloww'"),
        (("specs", "nope"), "unknown slice 'nope'"),
        (("specs", "linear-fast", "--episodes", "20000"), "episodes must be an integer in [0, 14849]"),
        (("specs", "test-1k", "--episodes", "-2"), "got '-2'"),
        (("specs", "test-1k", "--episodes", "0"), "expected a number >= 1, got '0'"),
        (("specs", "test-1k", "--episodes", "many"), "expected a whole number, got 'many'"),
        (("stats",), "SLICE"),
        ((), "COMMAND"),
        (("frobnicate",), "frobnicate"),
        (("export", "nowhere", "--out", "nowhere-out", "--workers", "65"), "--workers must be an integer in [0, 64]"),
    ],
)
def test_bad_input_exits_2_with_one_line(args, needle):
    result = run(*args)
    assert result.returncode == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert needle in lines[0]
    assert "Traceback" not in result.stderr


def test_specs_prints_jsonl_that_builds_back(tmp_path):
    result = run("specs", "test-1k", "--episodes", "12")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == 12
    assert [EpisodeSpec.from_json(line) for line in lines] == [spec_for("test-1k", i) for i in range(12)]
    path = tmp_path / "specs.jsonl"
    path.write_text(result.stdout)
    assert [s.episode_id for s in read_specs_jsonl(str(path))] == [f"test-1k:{i:06d}" for i in range(12)]


def test_specs_of_dyana_12m_keep_their_slice_names(capsys):
    assert main(["specs", "dyana-12m", "--episodes", "2"]) == 0
    specs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    got = [(s["slice"], s["episode_index"], s["seed"]) for s in specs]
    assert got == [("linear-fast", 0, 1), ("linear-fast", 1, 1)]


def test_specs_survive_a_closed_pipe():
    proc = subprocess.Popen(
        [sys.executable, "-m", "pipeline.cli_catalog", "specs", "dyana-12m"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert json.loads(proc.stdout.readline())["episode_index"] == 0
    proc.stdout.close()
    _, err = proc.communicate(timeout=120)
    assert b"Traceback" not in err


def test_stats_json(capsys):
    assert main(["stats", "test-1k", "--json"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats == slice_summary("test-1k")
    assert set(stats) >= {"total_episodes", "total_frames", "objects", "motion_types"}
    assert set(stats["objects"]) == {"categories", "rolling"}
    for name in ("linear", "circular", "harmonic"):
        assert set(stats["motion_types"][name]) == {"episodes", "parameter_sets", "mean_frames"}
    assert stats["total_episodes"] == 1_000


def test_stats_table_and_a_single_type_slice(capsys):
    assert main(["stats", "circular-fast", "--episodes", "500"]) == 0
    out = capsys.readouterr().out
    assert "500 episodes" in out
    assert any(line.split()[:2] == ["circular", "500"] for line in out.splitlines())
    assert any(line.split() == ["linear", "0", "0", "-"] for line in out.splitlines())
    assert main(["stats", "linear-slow", "--json", "--episodes", "10"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["motion_types"]["harmonic"] == {"episodes": 0, "parameter_sets": 0, "mean_frames": None}


def test_list_counts_every_slice(capsys):
    assert main(["list", "--json"]) == 0
    rows = {row["slice"]: row for row in json.loads(capsys.readouterr().out)}
    assert list(rows) == list(SLICES)
    assert all(rows[n]["episodes"] == SLICES[n].episodes for n in SLICES)
    assert rows["dyana-12m"]["frames"] == sum(rows[n]["frames"] for n in ATOMIC_SLICES)
    assert 11_500_000 <= rows["dyana-12m"]["frames"] <= 12_500_000
    assert rows["test-1k"]["frames"] == slice_summary("test-1k")["total_frames"]
    sizes = {name: row["expected_bytes"] for name, row in rows.items()}
    assert all(s["total"] == s["parquet"] + s["mcap"] and s["parquet"] > 0 and s["mcap"] > 0 for s in sizes.values())
    for key in ("parquet", "mcap"):
        parts = sum(sizes[n][key] for n in ATOMIC_SLICES)
        assert abs(sizes["dyana-12m"][key] - parts) <= len(ATOMIC_SLICES)  # the union is the sum of its parts
    per_frame = sizes["linear-fast"]["total"] / rows["linear-fast"]["frames"]
    assert 5_000 < per_frame < 50_000  # a 224 px JPEG twice (Parquet and MCAP) plus the states


@pytest.mark.slow(cover="tests/pipeline/test_cli_catalog.py::test_list_counts_every_slice")
def test_list_table():
    result = run("list")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == 2 + len(SLICES) and lines[-1].startswith("sizes: expected on disk")
    lines = lines[:-1]
    assert lines[1 + list(SLICES).index("dyana-12m")].split()[:4] == ["dyana-12m", "all", "all", "184,718"]
    assert lines[-2].split()[:4] == ["test-irregular", "mixed", "mixed", "99"]
    assert lines[-1].split()[:4] == ["test-complex", "mixed", "mixed", "300"]


@pytest.mark.slow(cover="tests/pipeline/test_cli_catalog.py::test_stats_json")
def test_stats_dyana_12m_reproduces_figure_4_from_the_shell():
    result = run("stats", "dyana-12m", "--json")
    assert result.returncode == 0, result.stderr
    stats = json.loads(result.stdout)
    assert stats["total_episodes"] == 184_718
    assert stats["objects"] == {"categories": 11, "rolling": 6}
    assert {n: stats["motion_types"][n]["episodes"] for n in ("linear", "circular", "harmonic")} == {
        "linear": 44_546,
        "circular": 89_709,
        "harmonic": 50_463,
    }
    assert {n: stats["motion_types"][n]["parameter_sets"] for n in ("linear", "circular", "harmonic")} == {
        "linear": 23_520,
        "circular": 44_508,
        "harmonic": 27_021,
    }
    for name, mean in (("linear", 36), ("circular", 78), ("harmonic", 64)):
        assert abs(stats["motion_types"][name]["mean_frames"] - mean) <= 0.05 * mean
    assert 11_500_000 <= stats["total_frames"] <= 12_500_000


def test_stats_and_specs_cover_the_harder_settings():
    stats = json.loads(run("stats", "test-complex", "--json").stdout)
    assert {k: v["episodes"] for k, v in stats["motion_types"].items()} == {
        "projectile": 100, "obstacle": 100, "irregular": 100
    }
    result = run("specs", "obstacle-fast", "--episodes", "2")
    assert result.returncode == 0, result.stderr
    specs = [EpisodeSpec.from_json(line) for line in result.stdout.splitlines()]
    assert [s.motion_type for s in specs] == ["obstacle", "obstacle"] and all(s.obstacles for s in specs)
    flight = EpisodeSpec.from_json(run("specs", "projectile-slow", "--episodes", "1").stdout.splitlines()[0])
    assert flight.motion.token_types == "P"
