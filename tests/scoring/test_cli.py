"""`scoring eval` end to end on tiny run folders written in the shard contract."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from scoring.cli import main
from scoring.io import load_run
from tests.pipeline.tamper import rehash
from tests.scoring.rollouts import CLOSED, Ep, png_size, write_run

OPEN = np.zeros(15, np.float32)


def closing(k: int, at: int) -> np.ndarray:
    """Joint angles open until frame ``at``, then closed."""
    joints = np.tile(OPEN, (k, 1))
    joints[at:] = CLOSED
    return joints


def xs(*values):
    """Palm points along X at y = 0.9: 0.4 over the top of the fixtures' objects (size 1, centre
    at y = 0), inside the ``paper`` reading's height band for S_loc."""
    return [[v, 0.9, 0.0] for v in values]


# Observe frames sit right on the object (d = 0) and are closed: they must not count.
# Acting frames 0..3: d = 2, 1, 0.2, 0.1 -> t_loc 2, E_loc 0.1; grasp from acting frame 3.
GOOD = dict(
    phases=["observe", "observe", "approach", "approach", "grasp", "hold"],
    palm=xs(0.0, 0.0, 2.0, 1.0, 0.2, 0.1),
    joints=np.concatenate([np.tile(CLOSED, (2, 1)), closing(4, 3)]),
    tips=[0.0, 0.0, 0.9, 0.5, 0.15, 0.05],
)
# Never within 0.3 while acting, never closed.
MISS = dict(phases=["observe", "approach", "approach", "hold"], palm=xs(0.0, 3.0, 2.0, 1.0), tips=[0.0, 0.8, 0.6, 0.7])


def run_main(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def run(tmp_path):
    episodes = [
        Ep(**GOOD, motion_type="linear", intercept_setting="fast"),
        Ep(**MISS, motion_type="circular", intercept_setting="slow", object="mug"),
        Ep(**GOOD, motion_type="harmonic", intercept_setting="fast", status="error"),
    ]
    return write_run(tmp_path / "oracle-run", episodes, policy="oracle")


def test_json_keys_and_values(capsys, run):
    code, out, err = run_main(capsys, "eval", str(run), "--json")
    assert code == 0, err
    result = json.loads(out)
    assert result["episodes"] == 3 and result["errors"] == 1
    assert result["label"] == "oracle" and result["policy"] == "oracle" and not result["ground_truth"]
    m = result["metrics"]
    assert list(m) == ["S_hold", "S_loc", "E_loc", "S_gra", "E_gra", "Q_smooth", "Q_line", "R_time", "S_grasp_contact"]  # headline first
    # the error episode is a failure although its frames equal GOOD's
    assert m["S_loc"] == pytest.approx(100 / 3)
    assert m["S_gra"] == pytest.approx(100 / 3)
    assert m["E_loc"] == pytest.approx((0.1 + 1.0 + 0.1) / 3, rel=1e-6)
    # E_gra at completion (the dyana and paper readings): GOOD completes at its 0.05 frame; MISS
    # never completes, so its last acting frame's 0.7 counts (the lenient reading's minimum is 0.6)
    assert m["E_gra"] == pytest.approx((0.05 + 0.7 + 0.05) / 3, rel=1e-6)
    # GOOD grasps with contact, but the hand-made hand holds nothing (the hold test), so Q,
    # weighted by the headline success S_hold, is 0 for all three (the reading test checks
    # GOOD's unweighted Q)
    assert m["S_grasp_contact"] == pytest.approx(100 / 3) and m["S_hold"] == 0.0
    assert m["Q_smooth"] == m["Q_line"] == 0.0
    assert result["averaged_over"] == {"E_loc": 3, "E_gra": 3, "Q_smooth": 3, "Q_line": 3, "R_time": 3}
    # A rollout's N is its acting horizon ceil(1.2 x 4) = 5 (it stops at grasp completion):
    # T = max(2, 3) + 1 = 4 of N = 5; the other two episodes score 0.
    assert m["R_time"] == pytest.approx((1 - 4 / 5) / 3 + 0 + 0)
    low, high = result["intervals"]["S_loc"]
    assert 0 < low < 100 / 3 < high < 100
    assert set(result["by_motion"]) == {"linear", "circular", "harmonic"}
    assert list(result["by_speed"]) == ["fast", "medium", "slow"]
    assert result["by_speed"]["medium"]["episodes"] == 0 and result["by_speed"]["medium"]["S_loc"] is None
    fast = result["by_speed"]["fast"]
    assert (fast["episodes"], fast["errors"], fast["S_loc"]) == (2, 1, 50.0)
    assert result["by_motion"]["circular"]["S_gra"] == 0.0
    assert result["by_motion"]["circular"]["Q_smooth"] == 0.0  # a failure's weighted Q
    assert result["by_motion"]["circular"]["averaged_over"]["Q_line"] == 1
    assert list(result["by_object"]) == ["tennis_ball", "mug"]


def test_r_time_counts_only_acting_frames(tmp_path, capsys):
    ep = Ep(phases=["observe"] * 3 + ["approach"] * 4 + ["grasp"] * 4, palm=xs(*[0.0] * 3, 3, 2, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1),
            joints=np.concatenate([np.tile(CLOSED, (3, 1)), closing(8, 4)]))
    built = write_run(tmp_path / "gt", [ep], policy=None)
    code, out, _ = run_main(capsys, "eval", str(built), "--json")
    assert json.loads(out)["metrics"]["R_time"] == pytest.approx(1 - 5 / 8)  # t_loc 2, t_gra 4 -> T 5 of N 8
    rollout = write_run(tmp_path / "r", [ep])
    code, out, _ = run_main(capsys, "eval", str(rollout), "--json")
    # A rollout's N is its acting horizon, ceil(1.2 x 8) = 10.
    assert json.loads(out)["metrics"]["R_time"] == pytest.approx(1 - 5 / 10)


def test_ground_truth_slice(tmp_path, capsys):
    folder = write_run(tmp_path / "linear-fast", [Ep(**GOOD), Ep(**GOOD)], policy=None)
    code, out, _ = run_main(capsys, "eval", str(folder), "--json")
    result = json.loads(out)
    assert code == 0
    assert result["ground_truth"] and result["policy"] is None and result["errors"] == 0
    assert result["label"] == "GT (linear-fast)"
    assert result["metrics"]["S_loc"] == 100.0 and result["metrics"]["S_gra"] == 100.0


def test_several_runs_give_a_list_and_one_table_row_each(tmp_path, capsys, run):
    gt = write_run(tmp_path / "gt", [Ep(**GOOD)], policy=None)
    code, out, _ = run_main(capsys, "eval", str(gt), str(run), "--json")
    result = json.loads(out)
    assert isinstance(result, list) and [r["label"] for r in result] == ["GT (gt)", "oracle"]
    code, out, _ = run_main(capsys, "eval", str(gt), str(run))
    assert code == 0
    lines = out.splitlines()
    assert lines[0].startswith("Run") and "S_hold (%)" in lines[0]
    assert lines[2].startswith("GT (gt)") and "100.00" in lines[2]
    assert lines[3].startswith("oracle") and "33.33" in lines[3]
    # the wide table is packed into tables that fit 100 columns, the run labels repeated in each
    headers = [line for line in lines if line.startswith("Run  ")]
    assert any("S_loc (%)" in h for h in headers) and any("R_time" in h for h in headers)
    assert max(len(line) for line in lines) <= 100
    assert "By motion type:" in out and "By interception setting:" in out


def test_same_policy_twice_gets_distinct_labels(tmp_path, capsys):
    a = write_run(tmp_path / "a", [Ep(**GOOD)])
    b = write_run(tmp_path / "b", [Ep(**MISS)])
    code, out, _ = run_main(capsys, "eval", str(a), str(b), "--json")
    assert [r["label"] for r in json.loads(out)] == ["oracle (a)", "oracle (b)"]


def test_plot_markdown_and_csv(tmp_path, capsys, run):
    png, md, table = tmp_path / "out.png", tmp_path / "out.md", tmp_path / "out.csv"
    code, _, err = run_main(capsys, "eval", str(run), "--plot", str(png), "--markdown", str(md), "--csv", str(table))
    assert code == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    text = md.read_text()
    assert "| oracle | 3 | 1 | 0.00 |" in text and "### By object" in text  # S_hold: the hand-made hands hold nothing
    rows = list(csv.DictReader(io.StringIO(table.read_text())))
    overall = rows[0]
    assert (overall["breakdown"], overall["group"], overall["episodes"]) == ("all", "all", "3")
    assert float(overall["S_loc"]) == pytest.approx(100 / 3)
    assert float(overall["S_loc_low"]) < float(overall["S_loc"]) < float(overall["S_loc_high"])
    medium = next(r for r in rows if r["breakdown"] == "speed" and r["group"] == "medium")
    assert medium["S_loc"] == "" and medium["episodes"] == "0"


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_per_episode_rows_name_each_episode_and_agree_with_the_summary(tmp_path, capsys, run, suffix):
    import pyarrow.csv as pa_csv
    import pyarrow.parquet as pq

    gt = write_run(tmp_path / "gt", [Ep(**GOOD)], policy=None)
    path = tmp_path / f"episodes{suffix}"
    code, out, err = run_main(capsys, "eval", str(run), str(gt), "--json", "--episodes", str(path))
    assert code == 0, err
    table = pq.read_table(path) if suffix == ".parquet" else pa_csv.read_csv(path)
    rows = table.to_pylist()
    assert [(r["label"], r["episode_index"]) for r in rows] == [("oracle", 0), ("oracle", 1), ("oracle", 2), ("GT (gt)", 0)]
    good, miss, failed, truth = rows
    assert (good["episode_id"], good["motion_type"], good["intercept_setting"]) == ("test:000000", "linear", "fast")
    assert (good["hand"], good["rollout_format"], good["status"]) == ("right", "observe-before-act", "ok")
    assert good["error"] in (None, "")  # CSV has no null string
    assert (good["t_loc"], good["t_gra"], good["localized"], good["grasped"]) == (2, 3, True, True)
    assert good["E_loc"] == pytest.approx(0.1, rel=1e-6) and good["R_time"] == pytest.approx(1 - 4 / 5)
    assert (miss["t_loc"], miss["t_gra"], miss["localized"], miss["Q_smooth"]) == (None, None, False, 0.0)  # Q x 0
    assert miss["object"] == "mug" and miss["E_loc"] == pytest.approx(1.0, rel=1e-6)
    # an error episode keeps the frames it recorded but counts as a failure, as in the summary
    assert failed["status"] == "error" and failed["error"]
    assert (failed["t_loc"], failed["localized"], failed["R_time"]) == (2, False, 0.0)
    assert truth["policy"] in (None, "") and truth["status"] == "ok"
    summary = json.loads(out)[0]["metrics"]
    oracle = rows[:3]
    for column, metric in (("localized", "S_loc"), ("grasped", "S_gra"), ("grasp_contact", "S_grasp_contact")):
        assert 100 * sum(r[column] for r in oracle) / 3 == pytest.approx(summary[metric])
    assert sum(r["R_time"] for r in oracle) / 3 == pytest.approx(summary["R_time"])
    assert sum(r["E_loc"] for r in oracle) / 3 == pytest.approx(summary["E_loc"])


def test_an_episodes_file_of_another_kind_is_refused_before_scoring(tmp_path, capsys, run):
    code, out, err = run_main(capsys, "eval", str(run), "--episodes", str(tmp_path / "rows.xlsx"))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "rows.xlsx" in err and ".parquet or .csv" in err
    assert not (tmp_path / "rows.xlsx").exists()


def test_multi_shard_run_loads_in_episode_order(tmp_path):
    eps = [Ep(**GOOD), Ep(**MISS), Ep(**MISS), Ep(**GOOD), Ep(**MISS)]
    data = load_run(write_run(tmp_path / "many", eps, shard_size=2))
    assert list(data.episode_index) == [0, 1, 2, 3, 4]
    assert list(np.diff(data.offsets)) == [4, 3, 3, 4, 3]
    assert data.palm_xyz.shape == (17, 3) and data.joint_angles.shape == (17, 15)
    assert data.palm_xyz[0, 0] == pytest.approx(2.0)  # first acting frame, not an observe frame


# --- bad input ----------------------------------------------------------------------


def test_not_a_rollout_folder(tmp_path, capsys):
    (tmp_path / "photos").mkdir()
    code, out, err = run_main(capsys, "eval", str(tmp_path / "photos"))
    assert code == 2 and out == ""
    assert "photos" in err and "catalog.json" in err and len(err.strip().splitlines()) == 1


def test_missing_folder(tmp_path, capsys):
    code, _, err = run_main(capsys, "eval", str(tmp_path / "nowhere"))
    assert code == 2 and "nowhere" in err and "no such folder" in err


def test_missing_column(tmp_path, capsys):
    folder = write_run(tmp_path / "bad", [Ep(**GOOD)], drop_frame_column="fingertip_distance")
    code, _, err = run_main(capsys, "eval", str(folder))
    assert code == 2
    assert "missing column 'fingertip_distance'" in err and "frames/000000-000000.parquet" in err
    assert "Traceback" not in err


def test_empty_run(tmp_path, capsys):
    folder = write_run(tmp_path / "empty", [])
    code, _, err = run_main(capsys, "eval", str(folder), "--json")
    assert code == 2 and "empty" in err and "the run is empty" in err


def test_corrupt_manifest(tmp_path, capsys, run):
    (run / "catalog.json").write_text("{not json")
    code, _, err = run_main(capsys, "eval", str(run))
    assert code == 2 and "catalog.json" in err


def test_usage_error_exits_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["eval"])
    assert exc.value.code == 2


def test_non_finite_state_is_refused(tmp_path, capsys):
    palm = xs(0.0, 3.0, float("nan"), 1.0)
    folder = write_run(tmp_path / "nan", [Ep(**GOOD), Ep(phases=MISS["phases"], palm=palm)])
    code, _, err = run_main(capsys, "eval", str(folder))
    assert code == 2 and "non-finite palm_pose" in err and "episode 1" in err


def test_unknown_status_and_phase_are_refused(tmp_path, capsys):
    folder = write_run(tmp_path / "status", [Ep(**GOOD, status="crashed")])
    code, _, err = run_main(capsys, "eval", str(folder))
    assert code == 2 and "unknown episode status 'crashed'" in err
    folder = write_run(tmp_path / "phase", [Ep(phases=["observe", "dance", "hold", "hold"], palm=MISS["palm"])])
    code, _, err = run_main(capsys, "eval", str(folder))
    assert code == 2 and "unknown phase 'dance'" in err


def test_plot_of_runs_at_100_and_0_percent(tmp_path, capsys):
    """Wilson bounds at the extremes equal the rate: the error bars must not go negative."""
    perfect = write_run(tmp_path / "perfect", [Ep(**GOOD) for _ in range(7)], policy="oracle")
    nothing = write_run(tmp_path / "nothing", [Ep(**MISS) for _ in range(7)], policy="still")
    png = tmp_path / "radar.png"
    code, _, err = run_main(capsys, "eval", str(perfect), str(nothing), "--plot", str(png))
    assert code == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"




def test_the_plot_is_a_column_wide_figure_with_the_papers_rows_on_request(tmp_path, capsys, run):
    plain, with_paper = tmp_path / "plain.png", tmp_path / "paper.png"
    assert run_main(capsys, "eval", str(run), "--plot", str(plain))[0] == 0
    code, out, err = run_main(capsys, "eval", str(run), "--plot", str(with_paper), "--paper")
    assert code == 0, err
    for path in (plain, with_paper):
        width, height = png_size(path)
        assert 900 <= width <= 1200, "3.5 in at 300 dpi: a paper's column"
        assert height > width
    assert png_size(with_paper)[1] > png_size(plain)[1], "the paper's rows add legend entries"
    assert "paper T3: GR00T-N1.5 (2.7B)" in out and "22.04" in out and "paper T4: GPT-4o" in out
    assert "paper T3" not in run_main(capsys, "eval", str(run))[1]


def test_radar_values_put_every_metric_on_zero_to_one_outward_better():
    from scoring.plot import RADAR_METRICS, radar_values

    metrics = {"S_loc": 50.0, "E_loc": 1.0, "S_gra": 100.0, "E_gra": 0.0, "Q_smooth": 0.8, "Q_line": -0.2, "R_time": None}
    assert RADAR_METRICS == ("S_loc", "E_loc", "S_gra", "E_gra", "Q_smooth", "Q_line", "R_time")
    values = radar_values(metrics)
    assert values[:6] == [0.5, 0.5, 1.0, 1.0, 0.8, 0.0]
    assert np.isnan(values[6])  # R_time missing ("-" in the table): a gap, not a 0 that reads as a score


def test_null_values_in_a_column_are_refused_in_one_line(tmp_path, capsys):
    """A frames file written by another tool with a null palm_pose must not crash with a traceback."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    folder = write_run(tmp_path / "nulls", [Ep(**GOOD)], policy=None)
    path = next((folder / "frames").glob("*.parquet"))
    table = pq.read_table(path)
    column = table.column("palm_pose").combine_chunks()
    values = column.to_pylist()
    values[3] = None
    index = table.schema.get_field_index("palm_pose")
    pq.write_table(table.set_column(index, pa.field("palm_pose", column.type), pa.array(values, column.type)), path)
    rehash(folder, 0, "frames")
    code, out, err = run_main(capsys, "eval", str(folder), "--json")
    assert code == 2 and out == ""
    assert "frames/000000-000000.parquet" in err and "'palm_pose'" in err and "null" in err
    assert len(err.strip().splitlines()) == 1


# --- outputs and completeness (issue 26) ---------------------------------------------


def _drop_shard(folder, index):
    """Remove shard ``index``'s files and re-hash catalog.json without it (a consistent manifest)."""
    from catalog.store.manifest import Manifest, load_manifest, write_manifest

    manifest = load_manifest(folder)
    for record in manifest.shards[index].files.values():
        (folder / record.path).unlink()
    shards = [s for i, s in enumerate(manifest.shards) if i != index]
    write_manifest(folder, Manifest.create(manifest.slice, manifest.seed, manifest.settings, shards,
                                           code=manifest.code, extra=manifest.extra))


@pytest.mark.parametrize(("dropped", "missing"), [(0, "episodes 0-1 are missing"), (1, "episodes 2-3 are missing")])
def test_a_run_with_a_removed_shard_is_refused_naming_the_missing_episodes(tmp_path, capsys, dropped, missing):
    folder = write_run(tmp_path / "run", [Ep(**GOOD), Ep(**MISS), Ep(**GOOD), Ep(**MISS), Ep(**GOOD)], shard_size=2)
    _drop_shard(folder, dropped)
    code, out, err = run_main(capsys, "eval", str(folder))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and missing in err and str(folder) in err


@pytest.mark.parametrize("flag", ["--episodes", "--csv", "--markdown", "--plot"])
def test_an_empty_output_path_is_refused_naming_the_flag(capsys, run, flag):
    code, out, err = run_main(capsys, "eval", str(run), flag, "")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and f"{flag}: the path is empty" in err


@pytest.mark.parametrize(("flag", "inside"), [
    ("--markdown", "catalog.json"),
    ("--csv", "stats.json"),
    ("--episodes", "frames/000000-000001.parquet"),
    ("--plot", "frames/new.png"),
])
def test_an_output_inside_the_run_being_scored_is_refused(capsys, run, flag, inside):
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    code, out, err = run_main(capsys, "eval", str(run), flag, str(run / inside))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and str(run / inside) in err and "being read" in err
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before


def test_an_output_that_is_a_folder_is_refused(tmp_path, capsys, run):
    code, out, err = run_main(capsys, "eval", str(run), "--csv", str(tmp_path))
    assert code == 2 and out == "" and err.count("\n") == 1 and "a folder" in err
    assert tmp_path.is_dir()


def test_outputs_to_a_device_and_a_fifo_are_written_as_such(tmp_path, capsys, run):
    import os
    import stat

    device = tmp_path / "null"
    try:
        os.mknod(device, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except OSError as exc:
        pytest.skip(f"cannot make a device node here: {exc}")
    fifo = tmp_path / "rows.csv"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    try:
        code, _, err = run_main(capsys, "eval", str(run), "--markdown", str(device), "--csv", str(fifo))
        assert code == 0, err
        assert os.read(reader, 1 << 16).startswith(b"label,run,slice,policy,reading,breakdown")
    finally:
        os.close(reader)
    assert stat.S_ISCHR(device.lstat().st_mode) and stat.S_ISFIFO(fifo.lstat().st_mode)


def test_csv_to_dev_null_leaves_dev_null_a_device(capsys, run):
    import os
    import stat

    code, _, err = run_main(capsys, "eval", str(run), "--csv", "/dev/null", "--markdown", "/dev/null")
    assert code == 0, err
    assert stat.S_ISCHR(os.lstat("/dev/null").st_mode)


@pytest.mark.parametrize("flag", ["--csv", "--markdown", "--episodes", "--plot", "--latency-plot"])
def test_an_output_url_is_refused_in_one_line_without_a_local_folder(tmp_path, capsys, monkeypatch, run, flag):
    monkeypatch.chdir(tmp_path)
    assert main(["eval", str(run), flag, "s3://bucket/out.parquet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{flag} 's3://bucket/out.parquet': is a URL" in err
    assert not (tmp_path / "s3:").exists()


# --- readings and the chance row ---------------------------------------------------------


def test_reading_flag_switches_the_ambiguous_rules(capsys, run):
    readings = {}
    for name in ("dyana", "paper", "lenient"):
        _, out, _ = run_main(capsys, "eval", str(run), "--json", "--reading", name)
        readings[name] = json.loads(out)
    dyana, paper, lenient = readings.values()
    assert [r["reading"] for r in readings.values()] == ["dyana", "paper", "lenient"]
    _, out, _ = run_main(capsys, "eval", str(run), "--json")
    assert json.loads(out) == dyana  # the default
    # MISS never completes its grasp: at its last frame 0.7, its minimum 0.6
    assert lenient["metrics"]["E_gra"] == pytest.approx((0.05 + 0.6 + 0.05) / 3, rel=1e-6)
    assert paper["metrics"]["E_gra"] == pytest.approx((0.05 + 0.7 + 0.05) / 3, rel=1e-6)
    # paper: Q unweighted over the one successful trajectory (GOOD, ok), and n_Q says so
    steps = np.array([1.0, 0.8, 0.1])
    assert paper["metrics"]["Q_smooth"] == pytest.approx(1 / (1 + steps.std() / steps.mean()), rel=1e-6)
    assert paper["metrics"]["Q_line"] == pytest.approx(1.0)
    # dyana: Q weighted by the headline success, S_hold, which the hand-made hands never reach
    assert dyana["metrics"]["S_hold"] == dyana["metrics"]["Q_smooth"] == dyana["metrics"]["Q_line"] == 0.0
    assert (paper["averaged_over"]["Q_smooth"], dyana["averaged_over"]["Q_smooth"]) == (1, 3)
    with pytest.raises(SystemExit) as exit_info:
        main(["eval", str(run), "--reading", "median"])
    assert exit_info.value.code == 2 and "median" in capsys.readouterr().err


def test_headline_is_the_first_metric_column_everywhere(tmp_path, capsys, run):
    md, table = tmp_path / "t.md", tmp_path / "t.csv"
    _, out, _ = run_main(capsys, "eval", str(run), "--markdown", str(md), "--csv", str(table))
    assert out.splitlines()[0].split()[3] == "S_hold"
    assert md.read_text().split("| Errors | ", 1)[1].startswith("S_hold (%)")
    header = table.read_text().splitlines()[0].split(",")
    assert header[header.index("grasped") + 1] == "S_hold"


def test_chance_row_is_the_best_blind_value_per_metric(tmp_path, capsys, run):
    # two blind runs on the run's three episodes: one localizes the first, the other never
    hit = write_run(tmp_path / "hit", [Ep(**GOOD), Ep(**MISS), Ep(**MISS)], policy="blind-centre")
    miss = write_run(tmp_path / "miss", [Ep(**MISS), Ep(**MISS), Ep(**MISS)], policy="blind-sweep")
    table = tmp_path / "t.csv"
    code, out, err = run_main(capsys, "eval", str(run), "--chance", str(hit), str(miss), "--csv", str(table))
    assert code == 0, err
    row = next(line for line in out.splitlines() if line.startswith("chance (best blind)"))
    assert "33.33" in row  # S_grasp_contact, S_loc and S_gra of the "hit" run
    _, out, _ = run_main(capsys, "eval", str(run), "--chance", str(hit), str(miss), "--json")
    chance = json.loads(out)["chance"]
    assert chance["metrics"]["S_loc"] == pytest.approx(100 / 3) and chance["best_of"]["S_loc"] == "blind-centre"
    assert chance["metrics"]["E_loc"] == pytest.approx((0.1 + 1.0 + 1.0) / 3, rel=1e-6)  # the lower
    assert chance["runs"] == ["blind-centre", "blind-sweep"]
    # the same best values within each motion type that holds episodes (the plot's bar marks)
    assert {group: by["S_loc"] for group, by in chance["by_motion"].items()} == {"linear": pytest.approx(100 / 3)}
    assert table.read_text().splitlines()[-1].startswith("chance (best blind)")


def test_the_plot_shades_what_blind_play_reaches(tmp_path, capsys, run):
    from PIL import Image

    hit = write_run(tmp_path / "hit", [Ep(**GOOD), Ep(**MISS), Ep(**MISS)], policy="blind-centre")
    plain, shaded = tmp_path / "plain.png", tmp_path / "chance.png"
    assert run_main(capsys, "eval", str(run), "--plot", str(plain))[0] == 0
    code, _, err = run_main(capsys, "eval", str(run), "--chance", str(hit), "--plot", str(shaded))
    assert code == 0, err

    def shade_pixels(path):  # the chance fill: #9A9A9A at 35% over white
        rgb = np.asarray(Image.open(path).convert("RGB"), dtype=int)
        return int((np.abs(rgb - 220).max(axis=2) <= 2).sum())

    assert shade_pixels(shaded) > shade_pixels(plain) + 500


def test_chance_runs_on_other_episodes_are_refused(tmp_path, capsys, run):
    short = write_run(tmp_path / "short", [Ep(**MISS), Ep(**MISS)], policy="blind-centre")
    code, out, err = run_main(capsys, "eval", str(run), "--chance", str(short))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "--chance short" in err and "other episodes" in err


def test_the_bars_leave_out_motion_types_no_run_holds(tmp_path):
    from scoring.cli import evaluate
    from scoring.plot import bar_groups

    linear = write_run(tmp_path / "linear", [Ep(**GOOD), Ep(**MISS)], policy="oracle")
    circular = write_run(tmp_path / "circular", [Ep(**GOOD, motion_type="circular")], policy="chase")
    one, both = evaluate([str(linear)]), evaluate([str(linear), str(circular)])
    assert bar_groups(one) == ["linear"]  # no circular or harmonic episode: no empty n/a group
    assert bar_groups(both) == ["linear", "circular"]  # one run without circular still shows n/a there


def test_a_latency_plot_of_no_run_with_a_latency_is_refused_before_any_output(tmp_path, capsys):
    """Before: a built slice's --latency-plot wrote an empty figure with exit 0 and a
    matplotlib UserWarning ('No artists with labels found') on stderr."""
    folder = write_run(tmp_path / "linear-fast", [Ep(**GOOD)], policy=None)
    plot, table = tmp_path / "latency.png", tmp_path / "table.csv"
    code, _, err = run_main(capsys, "eval", str(folder), "--latency-plot", str(plot), "--csv", str(table))
    assert code == 2 and "--latency-plot: no run to plot" in err and len(err.strip().splitlines()) == 1
    assert not plot.exists() and not table.exists()


def test_runs_over_different_episodes_are_named_in_one_note(tmp_path, capsys, run):
    """Before: `scoring eval runs/*` set 32 episodes beside 4 without a word."""
    code, _, err = run_main(capsys, "eval", str(run), str(run))
    assert code == 0 and "note:" not in err  # the same episodes: nothing to say
    fewer = write_run(tmp_path / "fewer", [Ep(**GOOD, motion_type="linear", intercept_setting="fast")], policy="still")
    code, out, err = run_main(capsys, "eval", str(run), str(fewer))
    assert code == 0 and "still" in out
    assert err.count("\n") == 1 and err.startswith("note: the runs hold different episodes (oracle-run: 3 of ")
    assert "fewer: 1 of " in err and "1 in common" in err
