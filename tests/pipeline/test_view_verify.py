"""`pipeline view` writes a loadable rerun recording; `catalog verify` rebuilds shards
byte for byte and names a tampered file."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from catalog.store.manifest import load_manifest
from pipeline.jobs.build import build
from schemas.errors import ShardError
from tests.console import run_here

BIN = Path(sys.executable).parent
SLICE = "circular-fast"


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("built")
    build(SLICE, out, episodes=3, resolution=48, shard_size=2, workers=0, progress=False)
    return out / SLICE


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / args[0]), *args[1:]], capture_output=True, text=True, timeout=300)


def test_view_writes_a_recording_rerun_can_read(built, tmp_path):
    out = tmp_path / "episode.rrd"
    result = _run("pipeline", "view", str(built), "--episode", "2", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert out.stat().st_size > 0
    assert _run("rerun", "rrd", "verify", str(out)).returncode == 0
    printed = _run("rerun", "rrd", "print", str(out)).stdout
    for entity in ("/world/camera/image", "/world/object/path", "/world/hand/skeleton", "/distance/palm_xz", "/phase/log"):
        assert entity in printed


def _read_rrd(path: Path) -> dict[str, list[dict]]:
    """Entity path -> its logged rows (component columns by name), read back with rerun's reader."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict]] = {}
    for chunk in RrdReader(path).stream():
        rows.setdefault(chunk.entity_path, []).extend(chunk.to_record_batch().to_pylist())
    return rows


def _component(rows: list[dict], name: str):
    return next(row[name] for row in rows if row.get(name) is not None)


def test_view_3d_world_is_right_handed_and_agrees_with_the_image(built, tmp_path):
    """Dyana's world is left-handed; the recording's is the MCAP's right-handed one (x right,
    y forward, z up). An object on the image's right must be on the camera's right in 3D
    too, and the logged camera (pose and pinhole) must put it on the image where the
    renderer drew it."""
    from catalog.tables.parquet_io import column_to_numpy
    from catalog.tables.reader import open_folder
    from generators.camera import project
    from pipeline.jobs.view import write_recording
    from schemas.rotations import quaternion_to_matrix

    folder = open_folder(built)
    size = folder.manifest.settings["resolution"]
    sides = []
    for episode in range(3):
        out = write_recording(built, episode, tmp_path / f"episode-{episode}.rrd")
        assert _run("rerun", "rrd", "verify", str(out)).returncode == 0
        logged = _read_rrd(out)
        assert _component(logged["/world"], "ViewCoordinates:xyz") == [[3, 5, 1]]  # R, F, U: right-handed
        camera = logged["/world/camera"]
        eye = np.array(_component(camera, "Transform3D:translation")[0])
        rotation = quaternion_to_matrix(np.array(_component(camera, "Transform3D:quaternion")[0]))
        assert _component(camera, "Pinhole:camera_xyz") == [[3, 2, 5]]  # optical frame: right, down, forward
        k = np.array(_component(camera, "Pinhole:image_from_camera")[0]).reshape(3, 3).T  # stored column-major
        assert "/world/camera/image" in logged
        right = rotation[:, 0]
        assert np.allclose(np.cross(right, rotation[:, 2]), -rotation[:, 1], atol=1e-6)  # right x forward = up

        points = sorted(logged["/world/object/centre"], key=lambda row: row["frame"])
        logged_xyz = np.array([row["Points3D:positions"][0] for row in points])
        _, frames = folder.episode(episode)
        pixels, _ = project(column_to_numpy(frames.column("object_pose"))[:, :3], size, size)
        in_camera = (logged_xyz - eye) @ rotation  # world -> optical frame
        through_pinhole = (in_camera @ k.T)[:, :2] / in_camera[:, 2:3]
        assert np.allclose(through_pinhole, pixels, atol=0.05), "the logged camera does not see what the image shows"
        offset = pixels[:, 0] - size / 2.0
        clear = np.abs(offset) > 1.0
        assert np.array_equal(np.sign((logged_xyz - eye) @ right)[clear], np.sign(offset)[clear])
        sides += list(np.sign(offset[clear]))
    assert 1.0 in sides  # the fixture has frames with the object on the image's right


def test_view_obstacle_boxes_are_the_same_boxes_in_the_right_handed_world(tmp_path):
    """Each logged box's corners (centre + rotated half sizes) are the obstacle's corners in
    Dyana's world with y and z swapped: the yaw quaternion is converted with the positions."""
    import math

    from catalog.tables.reader import open_folder
    from pipeline.jobs.view import write_recording
    from schemas.rotations import quaternion_to_matrix
    from schemas.spec import EpisodeSpec

    build("obstacle-fast", tmp_path, episodes=1, resolution=32, workers=0, progress=False)
    folder = tmp_path / "obstacle-fast"
    obstacles = EpisodeSpec.from_json(open_folder(folder).episode(0)[0]["spec"]).obstacles
    assert obstacles
    boxes = _read_rrd(write_recording(folder, 0, tmp_path / "obstacles.rrd"))["/world/obstacles"][0]
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    for k, o in enumerate(obstacles):
        yaw = quaternion_to_matrix(np.array([0.0, math.sin(0.5 * o.yaw), 0.0, math.cos(0.5 * o.yaw)]))
        dyana = np.array([o.centre[0], o.half_extents[1], o.centre[1]]) + (signs * o.half_extents) @ yaw.T
        rotation = quaternion_to_matrix(np.array(boxes["Boxes3D:quaternions"][k]))
        half = signs[:, [0, 2, 1]] * boxes["Boxes3D:half_sizes"][k]  # the same corners, in the same order
        logged = np.array(boxes["Boxes3D:centers"][k]) + half @ rotation.T
        assert np.allclose(logged, dyana[:, [0, 2, 1]], atol=1e-5)


def test_view_rejects_an_episode_the_folder_does_not_hold(built, tmp_path):
    result = _run("pipeline", "view", str(built), "--episode", "7", "--out", str(tmp_path / "x.rrd"))
    assert result.returncode == 2
    assert "no episode 7" in result.stderr
    assert not (tmp_path / "x.rrd").exists()


@pytest.mark.parametrize("damage", ["flip", "truncate"])
def test_view_refuses_a_damaged_shard_naming_it(capsys, built, tmp_path, damage):
    copy = tmp_path / SLICE
    shutil.copytree(built, copy)
    victim = copy / "frames" / "000002-000002.parquet"
    data = bytearray(victim.read_bytes())
    if damage == "flip":
        data[len(data) // 2] ^= 0xFF
    else:
        data = data[:-100]
    victim.write_bytes(bytes(data))
    result = run_here(capsys, "pipeline", "view", str(copy), "--episode", "2", "--out", str(tmp_path / "x.rrd"))
    assert result.returncode == 2
    assert "frames/000002-000002.parquet" in result.stderr and result.stderr.count("\n") == 1
    assert ("content changed" if damage == "flip" else "truncated") in result.stderr
    assert not (tmp_path / "x.rrd").exists()


def test_verify_rebuilds_identical_shards(capsys, built):
    result = run_here(capsys, "catalog", "verify", str(built))
    assert result.returncode == 0, result.stderr
    assert "2 rebuilt byte for byte" in result.stdout
    progress = [line for line in result.stderr.splitlines() if " episodes, " in line]
    assert progress[0].startswith("[rebuilding 0-1] 1/3 episodes, ") and progress[0].endswith("eta ?"), result.stderr
    assert progress[-1].startswith("[2/2 shards rebuilt] 3/3 episodes, ") and progress[-1].endswith("eta 0s")
    quiet = run_here(capsys, "catalog", "verify", str(built), "--quiet")
    assert quiet.returncode == 0 and quiet.stderr == "" and "2 rebuilt byte for byte" in quiet.stdout


def test_verify_names_a_tampered_file(built, tmp_path):
    copy = tmp_path / SLICE
    shutil.copytree(built, copy)
    victim = copy / "frames" / "000002-000002.parquet"
    data = bytearray(victim.read_bytes())
    data[len(data) // 2] ^= 0xFF
    victim.write_bytes(bytes(data))
    result = _run("catalog", "verify", str(copy), "--sample", "1")
    assert result.returncode != 0
    assert "frames/000002-000002.parquet" in result.stderr
    assert "Traceback" not in result.stderr


def test_verify_names_a_truncated_file(capsys, built, tmp_path):
    copy = tmp_path / SLICE
    shutil.copytree(built, copy)
    victim = copy / "mcap" / "000000-000001.mcap"
    victim.write_bytes(victim.read_bytes()[:100])
    result = run_here(capsys, "catalog", "verify", str(copy))
    assert result.returncode != 0
    assert "000000-000001.mcap" in result.stderr


def test_verify_rebuild_catches_what_hashes_cannot(capsys, built, tmp_path):
    """A file changed and re-hashed into catalog.json passes integrity; the rebuild still
    finds it."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from catalog.store.hashing import sha256_file
    from catalog.store.manifest import Manifest, load_manifest, write_manifest
    from catalog.store.records import ShardRecord

    copy = tmp_path / SLICE
    shutil.copytree(built, copy)
    victim = copy / "episodes" / "000002-000002.parquet"
    table = pq.read_table(victim)
    text = table.column("text").to_pylist()
    table = table.set_column(table.schema.get_field_index("text"), "text", pa.array([t + "!" for t in text]))
    pq.write_table(table, victim)
    manifest = load_manifest(copy)
    shards = []
    for shard in manifest.shards:
        raw = shard.to_dict()
        for entry in raw["files"].values():
            path = copy / entry["path"]
            entry["sha256"], entry["size"] = sha256_file(path), path.stat().st_size
        shards.append(ShardRecord.from_dict(raw))
    write_manifest(copy, Manifest.create(manifest.slice, manifest.seed, manifest.settings, shards,
                                         code=manifest.code, extra=manifest.extra))
    result = run_here(capsys, "catalog", "verify", str(copy))
    assert result.returncode == 2
    assert "episodes/000002-000002.parquet" in result.stderr
    assert "rebuilding gives different bytes" in result.stderr


def test_view_leaves_no_temporary_file_behind_on_failure(built, tmp_path, monkeypatch):
    import rerun as rr

    from pipeline.jobs.view import write_recording
    from schemas.errors import DyanaError

    folder = tmp_path / "x.rrd"
    folder.mkdir()
    with pytest.raises(DyanaError, match="is a folder"):
        write_recording(built, 0, folder)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.rrd"]

    def broken(*args, **kwargs):
        raise RuntimeError("logging failed")

    monkeypatch.setattr(rr, "Scalars", broken)
    with pytest.raises(RuntimeError, match="logging failed"):
        write_recording(built, 0, tmp_path / "y.rrd")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.rrd"]


def test_verify_names_settings_it_does_not_know(capsys, built, tmp_path):
    from catalog.store.manifest import Manifest, load_manifest, write_manifest

    copy = tmp_path / SLICE
    shutil.copytree(built, copy)
    manifest = load_manifest(copy)
    settings = dict(manifest.settings, hdr=True)
    write_manifest(copy, Manifest.create(manifest.slice, manifest.seed, settings, list(manifest.shards),
                                         code=manifest.code, extra=manifest.extra))
    result = run_here(capsys, "catalog", "verify", str(copy), "--quiet")
    assert result.returncode == 2
    assert "unknown settings ['hdr']" in result.stderr
    assert "Traceback" not in result.stderr


def test_edited_statistics_are_caught_by_verify_and_refused_by_the_loader(capsys, built, tmp_path):
    import json

    import catalog

    copy = tmp_path / SLICE
    shutil.copytree(built, copy)
    manifest = load_manifest(copy)
    assert manifest.stats is not None and manifest.stats.path == "stats.json"
    data = json.loads((copy / "stats.json").read_text())
    data["columns"]["action"]["std"] = [1.0] * 18
    (copy / "stats.json").write_text(json.dumps(data, sort_keys=True, indent=2) + "\n")
    result = run_here(capsys, "catalog", "verify", str(copy))
    assert result.returncode == 2 and "stats.json" in result.stderr and "Traceback" not in result.stderr
    with pytest.raises(ShardError, match="stats.json: "):
        _ = catalog.open(copy).stats


@pytest.fixture
def tiny_disk(tmp_path):
    """A 40 KiB file system (tmpfs), where the machine lets the tests mount one."""
    mount_point = tmp_path / "tiny"
    mount_point.mkdir()
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=40k", "tmpfs", str(mount_point)], capture_output=True)
    if made.returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    yield mount_point
    subprocess.run(["umount", str(mount_point)], check=True)


def test_a_build_on_a_full_disk_is_one_line_and_leaves_no_temporary(tiny_disk):
    result = _run("pipeline", "build", "--slice", SLICE, "--episodes", "4", "--shard-size", "2", "--resolution", "64",
                  "--workers", "1", "--out", str(tiny_disk), "--quiet")
    assert result.returncode == 2 and "No space left on device" in result.stderr, result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    # no temporary left; the folder lock (.lock) stays, as it always does
    assert [p.name for p in tiny_disk.rglob("*") if p.name.startswith(".")] == [".lock"]


def test_view_on_a_full_disk_is_refused_before_writing(built, tiny_disk):
    """rerun's writer can stall on a full disk, so view checks the free space first."""
    result = _run("pipeline", "view", str(built), "--episode", "0", "--out", str(tiny_disk / "ep.rrd"))
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "ep.rrd: not enough free space" in result.stderr and "Traceback" not in result.stderr
    assert list(tiny_disk.iterdir()) == []


def test_view_refuses_an_output_url_without_a_local_folder(built, tmp_path, monkeypatch, capsys):
    from pipeline.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["view", str(built), "--episode", "0", "--out", "s3://bucket/e0.rrd"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out 's3://bucket/e0.rrd': is a URL" in err
    assert not (tmp_path / "s3:").exists()


@pytest.fixture
def unwritable(tmp_path):
    """A folder no file can be made in: read-only to a user, a read-only tmpfs to root."""
    folder = tmp_path / "unwritable"
    folder.mkdir()
    if os.geteuid() != 0:
        folder.chmod(0o555)
        yield folder
        folder.chmod(0o755)
        return
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(folder)], capture_output=True)
    if made.returncode != 0:
        pytest.skip("cannot mount a read-only tmpfs here")
    yield folder
    subprocess.run(["umount", str(folder)], check=True)


def test_view_into_an_unwritable_folder_is_one_line_naming_it(capsys, built, unwritable):
    for out in (unwritable / "ep.rrd", unwritable / "new" / "ep.rrd"):
        result = run_here(capsys, "pipeline", "view", str(built), "--out", str(out))
        assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
        assert f"cannot write into the folder '{unwritable}'" in result.stderr and ".tmp-" not in result.stderr


def test_view_turns_a_recording_rerun_cannot_create_into_one_error(built, tmp_path, monkeypatch):
    import rerun as rr

    from pipeline.jobs.view import write_recording
    from schemas.errors import DyanaError

    def refused(self, path, *args, **kwargs):
        raise RuntimeError(f"Failed to create file: Permission denied (os error 13), path: {path}")

    monkeypatch.setattr(rr.RecordingStream, "save", refused)
    with pytest.raises(DyanaError, match=r"ep\.rrd: cannot write the recording \(Failed to create file"):
        write_recording(built, 0, tmp_path / "ep.rrd")
    assert list(tmp_path.iterdir()) == []
