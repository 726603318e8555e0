"""`catalog export A B ... --out X`: several folders as one LeRobot dataset (episodes
renumbered in order, provenance kept), up to date and refusals; the object's true pose
only with --environment-state."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

import catalog
from catalog.export.lerobot import ExportError, ExportSettings
from pipeline.cli_catalog import main as catalog_main
from pipeline.jobs.export import export
from tests.pipeline.test_export import _check_rows, _hf_rows, _tree

datasets = pytest.importorskip("datasets")

RESOLUTION = 64


@pytest.fixture(scope="module")
def sources(tmp_path_factory) -> list[Path]:
    from pipeline.jobs.build import build

    out = tmp_path_factory.mktemp("sources")
    build("linear-fast", out, episodes=3, shard_size=2, resolution=RESOLUTION, workers=0, progress=False)
    build("circular-fast", out, episodes=2, shard_size=2, resolution=RESOLUTION, workers=0, progress=False)
    return [out / "linear-fast", out / "circular-fast"]


def _items(folder: Path) -> list[dict]:
    with catalog.open(folder) as ds:
        return [ds[i] for i in range(len(ds))]


def _hash(folder: Path) -> str:
    return json.loads((folder / "catalog.json").read_text())["hash"]


@pytest.mark.parametrize("fmt", ["lerobot", "lerobot-v2.1"])
def test_two_folders_become_one_dataset_renumbered_with_their_provenance(sources, tmp_path, fmt):
    out = tmp_path / "both"
    report = export(sources, out, ExportSettings(fmt))
    assert (report.episodes, report.units_done) == (5, 3)
    first, second = (_items(s) for s in sources)
    renumbered = [i["episode_index"] for i in first] + [3 + i["episode_index"] for i in second]
    files = sorted((out / "data").rglob("*.parquet"))
    _check_rows(_hf_rows(files), first + second, episodes=renumbered)
    info = json.loads((out / "meta/info.json").read_text())
    assert info["total_episodes"] == 5 and "observation.environment_state" not in info["features"]
    if fmt == "lerobot":
        episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    else:
        episodes = [json.loads(line) for line in (out / "meta/episodes.jsonl").read_text().splitlines()]
    assert [e["episode_index"] for e in episodes] == [0, 1, 2, 3, 4]
    assert [e["dyana/source_episode_index"] for e in episodes] == [0, 1, 2, 0, 1]
    assert [e["dyana/source_hash"] for e in episodes] == [_hash(sources[0])] * 3 + [_hash(sources[1])] * 2
    assert [e["dyana/slice"] for e in episodes] == ["linear-fast"] * 3 + ["circular-fast"] * 2
    meta = json.loads((out / "meta/dyana.json").read_text())
    assert [(s["slice"], s["slice_hash"], s["first_episode"], s["episodes"]) for s in meta["sources"]] == [
        ("linear-fast", _hash(sources[0]), 0, 3), ("circular-fast", _hash(sources[1]), 3, 2)]
    stats = json.loads((out / "meta/stats.json").read_text())
    actions = np.stack([i["action"] for i in first + second]).astype(np.float64)
    np.testing.assert_allclose(stats["action"]["mean"], actions.mean(axis=0), rtol=1e-6, atol=1e-9)
    assert stats["action"]["count"] == [len(actions)] and "observation.environment_state" not in stats
    assert export(sources, out, ExportSettings(fmt)).up_to_date
    with pytest.raises(ExportError, match="another source or settings"):
        export(list(reversed(sources)), out, ExportSettings(fmt))


def test_the_object_pose_is_exported_only_when_asked_for(sources, tmp_path, capsys):
    out = tmp_path / "privileged"
    # in this process (--workers 1): worker processes are test_export's same-bytes test's
    assert catalog_main(["export", str(sources[0]), "--out", str(out), "--environment-state", "--workers", "1",
                         "--quiet"]) == 0
    assert "3 episodes" in capsys.readouterr().out
    info = json.loads((out / "meta/info.json").read_text())
    assert info["features"]["observation.environment_state"]["shape"] == [7]
    _check_rows(_hf_rows(sorted((out / "data").rglob("*.parquet"))), _items(sources[0]), environment_state=True)
    meta = json.loads((out / "meta/dyana.json").read_text())
    assert meta["job"]["settings"]["environment_state"] is True
    assert meta["mapping"]["observation.environment_state"] == ["object_pose"]


def test_an_interrupted_export_of_two_folders_resumes_to_the_same_bytes(sources, tmp_path, monkeypatch):
    from pipeline.jobs import export as export_module

    whole = tmp_path / "whole"
    export(sources, whole, ExportSettings("lerobot"))
    real, target = export_module.export_unit, tmp_path / "resumed"

    def failing(plan, first, report=None):
        if first == 3:  # the second folder's shard
            raise KeyboardInterrupt
        return real(plan, first, report)

    monkeypatch.setattr(export_module, "export_unit", failing)
    with pytest.raises(KeyboardInterrupt):
        export(sources, target, ExportSettings("lerobot"))
    monkeypatch.setattr(export_module, "export_unit", real)
    report = export(sources, target, ExportSettings("lerobot"))
    assert (report.units_resumed, report.units_done) == (2, 1)
    assert _tree(target) == _tree(whole)


def test_the_same_folder_twice_and_mixed_image_sizes_are_refused_in_one_line(sources, tmp_path, capsys):
    from catalog.store.manifest import Manifest, load_manifest, write_manifest

    code = catalog_main(["export", str(sources[0]), str(sources[0]), "--out", str(tmp_path / "x"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "the same build as" in err and "give each source once" in err
    edited = tmp_path / "edited"
    shutil.copytree(sources[1], edited)
    manifest = load_manifest(edited)
    write_manifest(edited, Manifest.create(manifest.slice, manifest.seed, {**manifest.settings, "resolution": 32},
                                           list(manifest.shards), code=manifest.code, extra=manifest.extra))
    with pytest.raises(ExportError, match="its images are 32 px, the sources before it 64 px"):
        export([sources[0], edited], tmp_path / "y", ExportSettings("lerobot"))
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
