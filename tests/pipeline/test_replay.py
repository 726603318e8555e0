"""`pipeline replay` re-executes built slices and rollouts byte for byte, and names the
first difference (shard, episode, frame, column) in a tampered one, even when the
manifest's hashes were updated so that integrity checks pass."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from catalog.store.manifest import load_manifest
from catalog.tables.integrity import verify_files
from pipeline.jobs.build import build
from pipeline.jobs.evaluate import evaluate
from pipeline.jobs.replay import replay
from schemas.errors import ReplayMismatch, ShardHashMismatch

from .tamper import flip_image_byte, rewrite_frames, set_state_value

BIN = Path(sys.executable).parent
RESOLUTION = 48


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("built")
    build("harmonic-fast", out, episodes=3, resolution=RESOLUTION, shard_size=2, workers=0, progress=False)
    return out / "harmonic-fast"


@pytest.fixture(scope="module")
def rollouts(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "oracle"
    evaluate("oracle", "test-1k", out, episodes=3, workers=0, resolution=RESOLUTION, shard_size=2, progress=False, summary=False)
    return out


def _pipeline(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "pipeline"), *args], capture_output=True, text=True, timeout=300)


def _copy(folder: Path, tmp_path: Path) -> Path:
    target = tmp_path / folder.name
    shutil.copytree(folder, target)
    return target


def test_replay_passes_on_a_built_slice(built):
    report = replay(built)
    assert (report.kind, report.slice, report.shards, report.episodes) == ("slice", "harmonic-fast", 2, 3)
    result = _pipeline("replay", str(built))
    assert result.returncode == 0, result.stderr
    assert "identical" in result.stdout


def test_replay_passes_on_rollouts(rollouts):
    report = replay(rollouts)
    assert (report.kind, report.slice, report.episodes) == ("rollouts", "test-1k", 3)
    assert report.frames == load_manifest(rollouts).frames
    result = _pipeline("replay", str(rollouts), "--quiet")
    assert result.returncode == 0, result.stderr


@pytest.mark.parametrize("which", ["built", "rollouts"])
def test_a_tampered_state_value_is_named(which, request, tmp_path):
    folder = _copy(request.getfixturevalue(which), tmp_path)
    rewrite_frames(folder, 1, lambda t: set_state_value(t, episode=2, frame=4, column="joint_angles", element=3, delta=1e-3))
    verify_files(folder)  # the files match the updated manifest: only re-execution can tell
    with pytest.raises(ReplayMismatch) as caught:
        replay(folder)
    exc = caught.value
    assert (exc.shard, exc.episode, exc.frame, exc.column) == ("000002-000002", 2, 4, "joint_angles")
    assert "joint_angles[3]" in str(exc)
    result = _pipeline("replay", str(folder), "--quiet")
    assert result.returncode == 1
    assert "episode 2" in result.stderr and "frame 4" in result.stderr and "column joint_angles" in result.stderr


@pytest.mark.parametrize("which", ["built", "rollouts"])
def test_a_tampered_jpeg_byte_is_named(which, request, tmp_path):
    folder = _copy(request.getfixturevalue(which), tmp_path)
    rewrite_frames(folder, 0, lambda t: flip_image_byte(t, episode=1, frame=2))
    verify_files(folder)
    with pytest.raises(ReplayMismatch) as caught:
        replay(folder)
    exc = caught.value
    assert (exc.shard, exc.episode, exc.frame, exc.column) == ("000000-000001", 1, 2, "image")
    assert "first difference at byte" in str(exc)


def test_a_tampered_mcap_is_named_by_file(built, tmp_path):
    """Columns all match but the MCAP copy of the data differs: replay names the file."""
    from catalog.store.hashing import sha256_file
    from catalog.store.manifest import Manifest, write_manifest
    from catalog.store.records import FileRecord, ShardRecord

    folder = _copy(built, tmp_path)
    manifest = load_manifest(folder)
    shard = manifest.shards[0]
    path = folder / shard.files["mcap"].path
    data = bytearray(path.read_bytes())
    at = data.find(b"harmonic")
    assert at > 0
    data[at] ^= 0x20
    path.write_bytes(bytes(data))
    files = dict(shard.files)
    files["mcap"] = FileRecord(shard.files["mcap"].path, sha256_file(path), path.stat().st_size)
    shards = [ShardRecord(shard.episodes, shard.frames, files), *manifest.shards[1:]]
    write_manifest(folder, Manifest.create(manifest.slice, manifest.seed, manifest.settings, shards, code=manifest.code))
    with pytest.raises(ReplayMismatch, match=r"mcap/000000-000001\.mcap differs from the replayed shard") as caught:
        replay(folder)
    assert caught.value.column == "mcap"


def test_replay_of_a_missing_folder_is_bad_input(tmp_path):
    result = _pipeline("replay", str(tmp_path / "nothing"))
    assert result.returncode == 2
    assert "catalog.json" in result.stderr and "Traceback" not in result.stderr


def test_a_tampered_mcap_on_disk_fails_even_with_the_manifest_untouched(built, tmp_path):
    """Replay reads through the checked reader: a corrupted or missing MCAP cannot pass
    (the file's sha256 no longer matches catalog.json)."""
    folder = _copy(built, tmp_path)
    path = folder / load_manifest(folder).shards[0].files["mcap"].path
    data = bytearray(path.read_bytes())
    data[data.find(b"harmonic")] ^= 0x20
    path.write_bytes(bytes(data))
    with pytest.raises(ShardHashMismatch, match=r"000000-000001\.mcap: content changed") as caught:
        replay(folder)
    assert caught.value.path == str(path)
    path.unlink()
    result = _pipeline("replay", str(folder))
    assert result.returncode == 2 and "000000-000001.mcap: file is missing" in result.stderr
    assert "Traceback" not in result.stderr
