"""Opt-in (``-m lerobot_real``): a v2.1 export converted to v3.0 by LeRobot's own converter,
with the command lines docs/guides/export-lerobot.md gives, equals the v3.0 export of the same
source: every data row, every episode's ``dyana/...`` facts; LeRobotDataset loads it.

LeRobot 0.4.x reads ``--root`` as the folder above ``<repo_id>`` (the dataset lies at
``ROOT/<repo_id>``); from 0.5 on ``--root`` is the dataset's own folder and the module moved
to ``lerobot.scripts``. Both convert in place: the v2.1 folder becomes ``<folder>_old``. The
releases' environments are ``.ci/lerobot-venvs``'s (a missing one is skipped).
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from catalog.export.lerobot import ExportSettings
from pipeline.jobs.export import export, files_intact

VENVS = Path(os.environ.get("DYANA_LEROBOT_VENVS", Path.home() / ".cache" / "dyana" / "lerobot-venvs"))
REPO_ID = "dyana/linear-fast"
pytestmark = pytest.mark.lerobot_real


def convert_command(python: str, version: str, root: Path) -> list[str]:
    """The converter's command line for the export at ``root / REPO_ID`` (as the guide gives it)."""
    if version.startswith("0.4."):
        return [python, "-m", "lerobot.datasets.v30.convert_dataset_v21_to_v30", f"--repo-id={REPO_ID}",
                f"--root={root}", "--push-to-hub=false"]
    return [python, "-m", "lerobot.scripts.convert_dataset_v21_to_v30", f"--repo-id={REPO_ID}",
            f"--root={root / REPO_ID}", "--push-to-hub=false"]


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    from pipeline.jobs.build import build

    out = tmp_path_factory.mktemp("convert-src")
    build("linear-fast", out, episodes=3, shard_size=2, resolution=64, workers=0, progress=False)
    return out / "linear-fast"


def _rows(folder: Path) -> list[dict]:
    return [row for path in sorted((folder / "data").rglob("*.parquet")) for row in pq.read_table(path).to_pylist()]


def _facts(folder: Path) -> list[dict]:
    table = pq.read_table(folder / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    return [{k: v for k, v in e.items() if k.startswith("dyana/") or k in ("episode_index", "length", "tasks")}
            for e in table]


@pytest.mark.parametrize("version", ["0.4.4", "0.6.1"])
def test_lerobots_converter_turns_the_v21_export_into_the_v30_export(source, tmp_path, version):
    python = VENVS / f"lerobot-{version}" / "bin" / "python"
    if not python.is_file():
        pytest.skip(f"no {python.parent.parent} (make it with .ci/lerobot-venvs {version})")
    root = tmp_path / "lerobot-root"
    dataset = root / REPO_ID
    export(source, dataset, ExportSettings("lerobot-v2.1"))
    direct = tmp_path / "v30"
    export(source, direct, ExportSettings("lerobot"))
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_HOME": str(tmp_path / "hf-home"),
           "HF_LEROBOT_HOME": str(tmp_path / "lerobot-home")}
    result = subprocess.run(convert_command(str(python), version, root), cwd=tmp_path, env=env, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-4000:]
    info = json.loads((dataset / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["total_frames"] == len(_rows(direct))
    assert _rows(dataset) == _rows(direct)
    assert _facts(dataset) == _facts(direct)
    old = dataset.with_name(dataset.name + "_old")  # the v2.1 export, moved aside whole
    assert files_intact(old, json.loads((old / "meta/dyana.json").read_text())["files"])
    load = ("from lerobot.datasets.lerobot_dataset import LeRobotDataset; import sys; "
            f"ds = LeRobotDataset({REPO_ID!r}, root=sys.argv[1], video_backend='pyav'); "
            "print(len(ds), ds.meta.total_episodes, tuple(ds[len(ds) - 1]['observation.images.ego'].shape))")
    loaded = subprocess.run([str(python), "-c", load, str(dataset)], env=env, capture_output=True, text=True,
                            timeout=600)
    assert loaded.returncode == 0, loaded.stderr[-4000:]
    assert loaded.stdout.split()[-5:] == [str(info["total_frames"]), "3", "(3,", "64,", "64)"]
