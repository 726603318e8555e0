"""The table-folder layout: --formats, and `catalog migrate` of a dataset 2.0.0 folder."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from catalog.store.manifest import Manifest, load_manifest, write_manifest
from catalog.store.records import LEGACY_LAYOUT, FileRecord, ShardRecord, shard_paths
from catalog.tables.integrity import verify_files
from catalog.tables.reader import open_folder
from pipeline.jobs.build import build
from pipeline.jobs.migrate import migrate
from pipeline.jobs.replay import replay
from schemas.errors import SettingsMismatch, ShardError
from tests.shard_files import shard_bytes, shard_names

from .tamper import unseal

BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("layout")
    manifest = build("linear-fast", out, episodes=3, resolution=32, shard_size=2, progress=False, workers=0)
    return manifest, out / "linear-fast"


def _as_legacy(source: Path, target: Path, version: str = "2.0.0", sealed: bool = False) -> Manifest:
    """``source`` rewritten as a dataset ``version`` folder in the old shards/ layout (its
    manifest unsealed, as the release before this one wrote it, unless ``sealed``)."""
    shutil.copytree(source, target)
    manifest = load_manifest(target)
    shards = []
    for shard in manifest.shards:
        old = shard_paths(*shard.episodes, LEGACY_LAYOUT)
        files = {}
        for kind, record in shard.files.items():
            (target / old[kind]).parent.mkdir(exist_ok=True)
            (target / record.path).rename(target / old[kind])
            files[kind] = FileRecord(old[kind], record.sha256, record.size)
        shards.append(ShardRecord(shard.episodes, shard.frames, files))
    for folder in ("frames", "episodes", "mcap"):
        (target / folder).rmdir()
    settings = {k: v for k, v in manifest.settings.items() if k != "formats"} | {"dataset_version": version}
    legacy = Manifest.create(manifest.slice, manifest.seed, settings, shards, code=manifest.code, stats=manifest.stats)
    write_manifest(target, legacy)
    if not sealed:
        unseal(target)
    return legacy


def test_each_table_has_its_folder_and_the_records_name_them(built):
    manifest, folder = built
    assert manifest.settings["formats"] == ["parquet", "mcap"]
    assert shard_names(folder) == sorted(f.path for s in manifest.shards for f in s.files.values())
    assert {p.split("/")[0] for p in shard_names(folder)} == {"frames", "episodes", "mcap"}


def test_formats_parquet_leaves_mcap_out_and_keeps_the_tables_byte_identical(built, tmp_path):
    manifest, folder = built
    result = subprocess.run(
        [str(BIN / "pipeline"), "build", "--slice", "linear-fast", "--episodes", "3", "--resolution", "32",
         "--shard-size", "2", "--workers", "1", "--formats", "parquet", "--out", str(tmp_path), "--quiet"],
        capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr
    lean = tmp_path / "linear-fast"
    assert not (lean / "mcap").exists()
    assert load_manifest(lean).settings["formats"] == ["parquet"]
    full = {p: b for p, b in shard_bytes(folder).items() if not p.startswith("mcap/")}
    assert shard_bytes(lean) == full
    verify_files(lean)
    assert open_folder(lean).frames(["timestamp"]).num_rows == manifest.frames


@pytest.mark.parametrize("value", ["mcap", "parquet,csv", ""])
def test_bad_formats_are_one_line(tmp_path, value):
    result = subprocess.run(
        [str(BIN / "pipeline"), "build", "--slice", "linear-fast", "--episodes", "1", "--formats", value,
         "--out", str(tmp_path)], capture_output=True, text=True, timeout=60,
    )
    assert result.returncode == 2 and result.stderr.count("\n") == 1 and "--formats" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "linear-fast").exists()


def test_a_manifest_whose_files_disagree_with_its_formats_is_refused(built, tmp_path):
    manifest, folder = built
    settings = dict(manifest.settings) | {"formats": ["parquet"]}
    with pytest.raises(ShardError, match=r"an mcap file, but settings.formats is \['parquet'\]"):
        Manifest.create(manifest.slice, manifest.seed, settings, manifest.shards, code=manifest.code)


def test_migrate_moves_a_2_0_folder_into_table_folders_and_keeps_its_hash(built, tmp_path):
    manifest, folder = built
    legacy = _as_legacy(folder, tmp_path / "old")
    before = {Path(p).name.split(".")[0] + kind: b for kind in ("frames", "episodes", "mcap")
              for p, b in shard_bytes(tmp_path / "old").items() if kind in p}
    with pytest.raises(ShardError, match="run `catalog migrate"):
        open_folder(tmp_path / "old")  # the previous release's manifest: sealed by the migration first
    with pytest.raises(ValueError):
        pd.read_parquet(tmp_path / "old" / "shards")  # the reason for the move: MCAP beside Parquet
    result = subprocess.run([str(BIN / "catalog"), "migrate", str(tmp_path / "old")], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "moved 6 files of 2 shards" in result.stdout and "catalog.json sealed" in result.stdout
    migrated = load_manifest(tmp_path / "old")
    assert migrated.hash == legacy.hash and migrated.settings["dataset_version"] == "2.0.0"
    assert not (tmp_path / "old" / "shards").exists()
    after = {Path(p).name.split(".")[0] + p.split("/")[0]: b for p, b in shard_bytes(tmp_path / "old").items()}
    assert after == before
    verify_files(tmp_path / "old")
    assert len(pd.read_parquet(tmp_path / "old" / "frames")) == manifest.frames
    again = migrate(tmp_path / "old")
    assert again[0].already


def test_an_interrupted_migration_finishes_when_run_again(built, tmp_path):
    _, folder = built
    legacy = _as_legacy(folder, tmp_path / "old")
    first = legacy.shards[0].files["frames"]
    target = tmp_path / "old" / shard_paths(*legacy.shards[0].episodes)["frames"]
    target.parent.mkdir()
    (tmp_path / "old" / first.path).rename(target)  # killed after its first move
    with pytest.raises(ShardError, match="run `catalog migrate"):
        open_folder(tmp_path / "old").frames()
    assert migrate(tmp_path / "old")[0].moved == 5
    verify_files(tmp_path / "old")


def test_a_folder_of_the_previous_release_is_refused_until_migrate_seals_it(built, tmp_path):
    manifest, folder = built
    old = tmp_path / "old"
    shutil.copytree(folder, old)
    unseal(old)
    before = {p: b for p, b in shard_bytes(old).items()}
    for command in (["catalog", "info", str(old)], ["scoring", "eval", str(old)]):
        result = subprocess.run([str(BIN / command[0]), *command[1:]], capture_output=True, text=True, timeout=60)
        assert result.returncode != 0 and result.stderr.count("\n") == 1, (command, result.stderr)
        assert f"{old}/catalog.json: written before Dyana sealed" in result.stderr
        assert f"run `catalog migrate {old}`" in result.stderr
    for check in (verify_files, replay):
        with pytest.raises(ShardError, match=f"run `catalog migrate {old}`"):
            check(old)
    result = subprocess.run([str(BIN / "catalog"), "migrate", str(old)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "every file checked, catalog.json sealed (2 shards, hash unchanged)" in result.stdout
    assert load_manifest(old).hash == manifest.hash and shard_bytes(old) == before
    assert (old / "catalog.json").read_text() == (folder / "catalog.json").read_text()
    assert migrate(old)[0].already


def test_migrate_seals_nothing_it_has_not_checked(built, tmp_path):
    _, folder = built
    old = tmp_path / "old"
    shutil.copytree(folder, old)
    unseal(old)
    frames = old / load_manifest(old, sealed=False).shards[1].files["frames"].path
    data = bytearray(frames.read_bytes())
    data[len(data) // 2] ^= 1
    frames.write_bytes(bytes(data))
    unsealed = (old / "catalog.json").read_text()
    with pytest.raises(ShardError, match=f"{frames}: content changed"):
        migrate(old)
    frames.write_bytes((folder / frames.relative_to(old)).read_bytes())
    (old / "frames" / "stray.parquet").write_bytes(b"x")
    with pytest.raises(ShardError, match="frames/stray.parquet: not listed in catalog.json"):
        migrate(old)
    assert (old / "catalog.json").read_text() == unsealed


def test_unreadable_dataset_versions_are_named(built, tmp_path):
    _, folder = built
    _as_legacy(folder, tmp_path / "old", version="1.0.0", sealed=True)
    with pytest.raises(SettingsMismatch, match="dataset_version is '1.0.0'"):
        open_folder(tmp_path / "old")


def test_a_2_0_folder_is_not_rebuilt_by_this_code(built, tmp_path):
    _, folder = built
    _as_legacy(folder, tmp_path / "old")
    migrate(tmp_path / "old")
    assert open_folder(tmp_path / "old").frames(["timestamp"]).num_rows == load_manifest(folder).frames  # reads
    result = subprocess.run([str(BIN / "catalog"), "verify", str(tmp_path / "old"), "--quiet"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "written as dataset version '2.0.0'" in result.stderr
    assert result.stderr.count("\n") == 1
