"""An export others can load and cite: ``datasets.load_dataset(EXPORT)`` loads its frames
(the card's ``configs``), ``croissant.json`` validates with `mlcroissant` and its records are
the frames and episodes, and ``meta/camera.json``'s intrinsics and pose project as the
renderer does and equal the MCAP calibration."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from catalog.export.card import CITATION, LICENSE_HUB
from tests.pipeline import test_export
from tests.pipeline.test_export import EPISODES, RESOLUTION, SHARD_SIZE

datasets = pytest.importorskip("datasets")

FORMATS = ("lerobot", "lerobot-v2.1")
#: The source and its exports are test_export's fixtures: one build, one export per format.
built, exports = test_export.built, test_export.exports


def _data_rows(out: Path) -> list[dict]:
    return [row for path in sorted((out / "data").rglob("*.parquet")) for row in pq.read_table(path).to_pylist()]


@pytest.mark.parametrize("fmt", FORMATS)
def test_load_dataset_of_the_export_folder_gives_its_frames(exports, tmp_path, fmt):
    out = exports[fmt]
    loaded = datasets.load_dataset(str(out), split="train", cache_dir=str(tmp_path / "hf"))
    rows = _data_rows(out)
    info = json.loads((out / "meta/info.json").read_text())
    assert len(loaded) == len(rows) == info["total_frames"]
    assert loaded.column_names == list(rows[0])
    assert sorted(loaded.to_list(), key=lambda r: r["index"]) == sorted(rows, key=lambda r: r["index"])


def test_without_the_card_load_dataset_reads_the_episodes_table_too_and_fails(exports, tmp_path):
    """Why the card's ``configs`` are there: v3.0's meta/ holds Parquet tables of other columns."""
    bare = tmp_path / "bare"
    shutil.copytree(exports["lerobot"], bare)
    (bare / "README.md").unlink()
    with pytest.raises(Exception, match="column names don't match|An error occurred while generating"):
        datasets.load_dataset(str(bare), split="train", cache_dir=str(tmp_path / "hf"))


@pytest.mark.parametrize("fmt", FORMATS)
def test_the_card_names_license_citation_configs_and_the_slice_hash(built, exports, fmt):
    hub = pytest.importorskip("huggingface_hub")
    card = hub.DatasetCard.load(exports[fmt] / "README.md")
    assert card.data.license == LICENSE_HUB
    assert card.data.configs == [{"config_name": "default", "data_files": "data/*/*.parquet"}]
    slice_hash = json.loads((built / "catalog.json").read_text())["hash"]
    assert f"slice hash `{slice_hash}`" in card.text and CITATION in card.text
    assert f"--episodes {EPISODES} --shard-size {SHARD_SIZE} --resolution {RESOLUTION}" in card.text
    assert f"--format {fmt} --out EXPORT" in card.text


@pytest.mark.parametrize("fmt", FORMATS)
def test_croissant_validates_hashes_every_file_and_its_records_are_the_frames(exports, fmt):
    mlc = pytest.importorskip("mlcroissant")
    out = exports[fmt]
    dataset = mlc.Dataset(str(out / "croissant.json"))  # validates: ValidationError otherwise
    issues = dataset.metadata.ctx.issues
    assert not issues.errors
    assert [w for w in issues.warnings if "datePublished" not in w] == []  # no date: the bytes are the source's
    document = json.loads((out / "croissant.json").read_text())
    objects = {d["contentUrl"]: d for d in document["distribution"] if d["@type"] == "cr:FileObject"}
    listed = json.loads((out / "meta/dyana.json").read_text())["files"]
    assert set(objects) == set(listed) - {"croissant.json"}
    for path, entry in objects.items():
        data = (out / path).read_bytes()
        assert entry["sha256"] == hashlib.sha256(data).hexdigest() and entry["contentSize"] == f"{len(data)} B"
    frames = sorted(dataset.records("frames"), key=lambda r: r["frames/index"])
    rows = sorted(_data_rows(out), key=lambda r: r["index"])
    assert len(frames) == len(rows)
    for record, row in zip(frames, rows):
        assert {key.removeprefix("frames/"): value for key, value in record.items()} == row
    episodes = list(dataset.records("episodes"))
    assert [r["episodes/episode_index"] for r in episodes] == list(range(EPISODES))
    assert sum(r["episodes/length"] for r in episodes) == len(rows)
    assert {r["episodes/dyana/motion_type"] for r in episodes} == {b"linear"}


def test_camera_json_projects_as_the_renderer_and_equals_the_mcap_calibration(built, exports):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from generators.camera import points_in_view, project

    camera = json.loads((exports["lerobot"] / "meta/camera.json").read_text())
    assert camera == json.loads((exports["lerobot-v2.1"] / "meta/camera.json").read_text())
    assert (camera["width"], camera["height"], camera["cx"], camera["cy"]) == (64, 64, 32.0, 32.0)
    k, pose = np.array(camera["K"]), np.array(camera["world_to_camera"])
    assert k[0, 0] == camera["fx"] == camera["fy"] == pytest.approx(32 / np.tan(np.radians(30)), rel=1e-12)
    points = np.random.default_rng(0).uniform([-4, 0, -1], [4, 3, 12], (2000, 3))
    points = points[points_in_view(points)]
    assert len(points) > 100
    optical = points @ pose[:3, :3].T + pose[:3, 3]
    pixels = optical @ k.T
    pixels = pixels[:, :2] / pixels[:, 2:]
    expected, depth = project(points, 64, 64)
    np.testing.assert_allclose(pixels, expected, atol=1e-8)
    np.testing.assert_allclose(optical[:, 2], depth, atol=1e-9)
    mcap = next((built / "mcap").glob("*.mcap"))
    with mcap.open("rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        _, _, _, calibration = next(reader.iter_decoded_messages(topics=["/camera/calibration"]))
    assert (calibration.width, calibration.height) == (64, 64)
    np.testing.assert_allclose(np.array(calibration.K).reshape(3, 3), k, rtol=1e-12)
    with mcap.open("rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        _, _, _, transforms = next(reader.iter_decoded_messages(topics=["/tf"]))
    tf = next(t for t in transforms.transforms if t.child_frame_id == "camera")
    position = [tf.translation.x, tf.translation.y, tf.translation.z]
    rotation = [tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w]
    np.testing.assert_allclose(camera["mcap_pose"]["position"], position, atol=1e-12)
    np.testing.assert_allclose(camera["mcap_pose"]["quaternion_xyzw"], rotation, atol=1e-12)


def test_the_cards_build_command_rebuilds_the_sources_slice_hash(built, exports, tmp_path, monkeypatch):
    import re
    import shlex

    from pipeline.cli import main as pipeline_main

    text = (exports["lerobot"] / "README.md").read_text()
    command = re.search(r"`(pipeline build [^`]+)` builds it", text).group(1)
    argv = shlex.split(command)[1:]
    assert argv[-2:] == ["--out", "out"]
    monkeypatch.chdir(tmp_path)
    assert pipeline_main([*argv, "--workers", "1", "--quiet"]) == 0
    rebuilt = json.loads((tmp_path / "out/linear-fast/catalog.json").read_text())["hash"]
    assert rebuilt == json.loads((built / "catalog.json").read_text())["hash"]
