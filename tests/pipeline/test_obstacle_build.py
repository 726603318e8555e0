"""An obstacle slice end to end from the command line: build (frames record the hand's
clearance, the MCAP draws the obstacles), verify, replay, view, evaluate and score; and a
slice without obstacles keeps its old tables."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from catalog.tables.mcap_layout import OBSTACLE_TOPIC
from catalog.tables.mcap_reader import count_messages, iter_messages, read_timeline
from catalog.tables.reader import open_folder
from schemas.errors import SpecError
from schemas.obstacles import OBSTACLE_MARGIN
from schemas.spec import EpisodeSpec

BIN = Path(sys.executable).parent


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / args[0]), *args[1:]], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """``pipeline build`` through its entry point in this process (what the console script
    calls; a process of its own cost its start)."""
    from pipeline.cli import main

    out = tmp_path_factory.mktemp("obstacles")
    assert main(["build", "--slice", "obstacle-fast", "--episodes", "3", "--resolution", "48", "--workers", "1",
                 "--quiet", "--out", str(out)]) == 0
    return out / "obstacle-fast"


def test_frames_record_the_clearance_the_ground_truth_keeps(built):
    manifest = json.loads((built / "catalog.json").read_text())
    assert manifest["settings"]["obstacle_clearance"] is True
    frames_file = next(p for p in built.rglob("*.parquet") if p.parent.name == "frames")
    table = pq.read_table(frames_file)
    clearance = table.column("obstacle_clearance").to_numpy()
    assert np.isfinite(clearance).all() and clearance.min() >= OBSTACLE_MARGIN - 1e-5
    assert ds.dataset(frames_file).to_table(columns=["obstacle_clearance"]).num_rows == table.num_rows


def test_the_mcap_draws_each_episodes_obstacles(built):
    mcap = next(built.rglob("*.mcap"))
    counts = count_messages(mcap)
    assert counts[(OBSTACLE_TOPIC, "foxglove.SceneUpdate")] == counts[("/camera/image", "foxglove.CompressedImage")]
    folder = open_folder(built)
    obstacles = {row["episode_index"]: EpisodeSpec.from_json(row["spec"]).obstacles
                 for shard in folder for row in shard.episodes(["episode_index", "spec"]).to_pylist()}
    seen = {}
    timeline = read_timeline(mcap)
    for message in iter_messages(mcap, topics=[OBSTACLE_TOPIC]):
        episode, _ = timeline.locate(message.log_time_ns)
        seen[episode] = len(message.message.entities)
        assert [d.type for d in message.message.deletions] == [1]  # ALL
    assert seen == {k: len(v) for k, v in obstacles.items()}


def test_verify_replay_view_and_score(built, tmp_path, capsys):
    """The commands' own entry points (what their console scripts call) in this process, but
    ``view`` (rerun's SDK stays out of the test process): a process each cost its start, and
    the commands' processes are tested on other folders (test_replay.py, test_view_verify.py,
    tests/scoring)."""
    from pipeline.cli import main as pipeline_main
    from pipeline.cli_catalog import main as catalog_main
    from scoring.cli import main as scoring_main

    assert catalog_main(["verify", str(built)]) == 0, capsys.readouterr().err
    assert pipeline_main(["replay", str(built)]) == 0, capsys.readouterr().err
    assert capsys.readouterr().out.endswith(": identical\n")
    view = run("pipeline", "view", str(built), "--episode", "1", "--out", str(tmp_path / "e1.rrd"))
    assert view.returncode == 0, view.stderr
    assert scoring_main(["eval", str(built), "--json"]) == 0, capsys.readouterr().err
    assert json.loads(capsys.readouterr().out)["obstacles"] == {"episodes": 3, "collisions": 0, "collision_rate": 0.0,
                                                               "contact": "fail"}


def test_a_closed_loop_run_on_test_complex_records_clearance_and_scores_contacts(tmp_path, capsys):
    from pipeline.cli import main

    code = main(["eval", "--policy", "chase", "--slice", "test-complex", "--episodes", "3", "--resolution", "48",
                 "--workers", "1", "--quiet", "--out", str(tmp_path / "run")])
    assert code == 0, capsys.readouterr().err
    frames_file = next(p for p in (tmp_path / "run").rglob("*.parquet") if p.parent.name == "frames")
    table = pq.read_table(frames_file, columns=["episode_index", "obstacle_clearance"])
    clearance = table.column("obstacle_clearance").to_numpy()
    episode = table.column("episode_index").to_numpy()
    assert np.isinf(clearance[episode != 1]).all() and np.isfinite(clearance[episode == 1]).all()
    from scoring.cli import main as scoring_main

    capsys.readouterr()
    assert scoring_main(["eval", str(tmp_path / "run"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["obstacles"]["episodes"] == 1


def test_a_slice_without_obstacles_keeps_its_tables(tmp_path):
    from pipeline.jobs.build import build

    build("linear-fast", tmp_path, episodes=1, resolution=32, workers=0, progress=False)
    folder = tmp_path / "linear-fast"
    assert "obstacle_clearance" not in json.loads((folder / "catalog.json").read_text())["settings"]
    frames_file = next(p for p in folder.rglob("*.parquet") if p.parent.name == "frames")
    assert "obstacle_clearance" not in pq.read_schema(frames_file).names
    assert all(topic != OBSTACLE_TOPIC for topic, _ in count_messages(next(folder.rglob("*.mcap"))))


def test_the_dataloader_selects_obstacle_episodes(built):
    import catalog

    with catalog.open(built, motion_type="obstacle") as data:
        assert len(data.episodes) == 3 and {e.motion_type for e in data.episodes} == {"obstacle"}
        assert data[0]["image"].shape[:2] == (48, 48)
    with pytest.raises(SpecError, match=r"no episode matches the filters \(motion_type=\['projectile'\]\)"):
        catalog.open(built, motion_type="projectile")  # refused, saying what the folder holds
