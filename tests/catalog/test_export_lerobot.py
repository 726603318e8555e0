"""The v2.1 export loaded by the real ``LeRobotDataset`` (slow; needs a Python with lerobot).

LeRobot 0.3.2 is the release this test pins (0.4.x installs on Python 3.11 too); it cannot share
Dyana's test environment (it needs torchvision, whose PyPI build wants its own torch),
so the test runs it in the interpreter named by ``DYANA_LEROBOT_PYTHON`` and compares
what it loads with the source. Set up as in docs/guides/export-lerobot.md: a venv with
``pip install lerobot==0.3.2`` and the system's FFmpeg libraries for torchcodec.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import catalog
from catalog.export.lerobot import ExportSettings
from catalog.export.video import psnr
from pipeline.jobs.export import export

LEROBOT_PYTHON = os.environ.get("DYANA_LEROBOT_PYTHON")
pytestmark = [
    pytest.mark.slow(cover="tests/pipeline/test_export.py::test_v30_export_round_trips_every_state_action_and_frame"),
    pytest.mark.skipif(not LEROBOT_PYTHON, reason="set DYANA_LEROBOT_PYTHON to a Python with lerobot installed"),
]


def test_lerobot_dataset_loads_the_v21_export_item_for_item(tmp_path):
    from pipeline.jobs.build import build

    build("circular-fast", tmp_path / "src", episodes=4, shard_size=2, resolution=96, workers=1, progress=False)
    source = tmp_path / "src" / "circular-fast"
    out = tmp_path / "export"
    export(source, out, ExportSettings("lerobot-v2.1", environment_state=True))  # every key keys="lerobot" gives
    npz = tmp_path / "items.npz"
    script = Path(__file__).with_name("lerobot_items.py")
    result = subprocess.run([LEROBOT_PYTHON, str(script), str(out), str(npz), "torchcodec"],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    loaded = np.load(npz)
    with catalog.open(source) as ds:
        items = [ds[i] for i in range(len(ds))]
    assert int(loaded["num_episodes"]) == 4 and len(loaded["index"]) == len(items)
    for k, item in enumerate(items):
        np.testing.assert_array_equal(loaded["observation.state"][k], np.concatenate([item["palm_pose"], item["joint_angles"]]))
        np.testing.assert_array_equal(loaded["action"][k], item["action"])
        np.testing.assert_array_equal(loaded["observation.environment_state"][k], item["object_pose"])
        assert loaded["frame_index"][k] == item["frame_index"] and loaded["episode_index"][k] == item["episode_index"]
        assert loaded["index"][k] == k and str(loaded["task"][k]) == item["text"]
        assert psnr(loaded["image"][k], item["image"]) >= 33.0
    with catalog.open(source, keys="lerobot") as keyed:
        item = keyed[0]
        assert sorted(item) == loaded["keys"].tolist(), "keys='lerobot' gives LeRobotDataset's keys"
        assert item["observation.images.ego"].shape == tuple(loaded["image_shape"])
        assert item["task_index"] == loaded["task_index"][0] and item["index"] == loaded["index"][0]
    sys.stdout.write(f"lerobot {result.stdout.strip()} loaded {len(items)} frames\n")
