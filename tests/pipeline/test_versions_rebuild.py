"""A build records the library versions that determine its bytes; when a re-executed shard's
bytes differ, `pipeline replay` and `catalog verify` name each recorded version that differs
from the installed one, and say nothing of versions when they all match."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from catalog.store.manifest import SEAL_KEY, Manifest, load_manifest, seal_of, write_manifest
from catalog.store.versions import VERSIONS_KEY, installed_versions
from pipeline.jobs.build import build
from pipeline.jobs.migrate import migrate
from pipeline.jobs.replay import replay
from pipeline.jobs.verify import verify
from schemas.errors import ReplayMismatch, ShardError

from .tamper import rewrite_frames, set_state_value

SLICE = "harmonic-fast"


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("built")
    build(SLICE, out, episodes=2, resolution=32, shard_size=2, workers=0, progress=False)
    return out / SLICE


def _tampered(built: Path, tmp_path: Path, versions: dict | None) -> Path:
    """A copy whose frames differ from what re-execution gives (re-hashed, so only a rebuild
    can tell), its manifest re-sealed recording ``versions``."""
    folder = tmp_path / SLICE
    shutil.copytree(built, folder)
    rewrite_frames(folder, 0, lambda t: set_state_value(t, episode=1, frame=3, column="joint_angles", element=2, delta=1e-3))
    manifest = load_manifest(folder)
    write_manifest(folder, Manifest.create(manifest.slice, manifest.seed, manifest.settings, manifest.shards,
                                           code=manifest.code, extra=manifest.extra, stats=manifest.stats,
                                           versions=versions))
    return folder


def _failures(folder: Path) -> tuple[str, str]:
    with pytest.raises(ReplayMismatch) as replayed:
        replay(folder)
    with pytest.raises(ShardError) as verified:
        verify(folder)
    return str(replayed.value), str(verified.value)


def test_a_build_records_the_installed_versions(built):
    assert load_manifest(built).versions == installed_versions()


def test_matching_versions_are_not_mentioned(built, tmp_path):
    for message in _failures(_tampered(built, tmp_path, installed_versions())):
        assert "column joint_angles" in message
        assert "recorded" not in message.split("replay gives")[-1] and "installed" not in message


def test_a_recorded_version_that_differs_is_named(built, tmp_path):
    installed = installed_versions()
    folder = _tampered(built, tmp_path, {**installed, "pyarrow": "0.0.1", "numpy": "0.0.2"})
    replayed, verified = _failures(folder)
    note = f"; recorded numpy 0.0.2, installed {installed['numpy']}; recorded pyarrow 0.0.1, installed {installed['pyarrow']}"
    assert replayed.endswith(note) and "column joint_angles" in replayed
    assert verified.endswith(note) and "rebuilding gives different bytes" in verified


def test_an_installed_version_that_differs_is_named(built, tmp_path, monkeypatch):
    real = installed_versions()
    folder = _tampered(built, tmp_path, real)
    monkeypatch.setattr("catalog.store.versions.installed_versions", lambda: {**real, "pybullet": "9.9.9"})
    for message in _failures(folder):
        assert message.endswith(f"; recorded pybullet {real['pybullet']}, installed 9.9.9")


def test_a_folder_without_the_record_says_so(built, tmp_path):
    for message in _failures(_tampered(built, tmp_path, None)):
        assert message.endswith("; the folder records no library versions (written before Dyana recorded them)")


def test_a_folder_written_before_the_record_verifies_and_migrate_leaves_it(built, tmp_path):
    folder = tmp_path / SLICE
    shutil.copytree(built, folder)
    manifest = load_manifest(folder)
    write_manifest(folder, Manifest.create(manifest.slice, manifest.seed, manifest.settings, manifest.shards,
                                           code=manifest.code, extra=manifest.extra, stats=manifest.stats))
    before = (folder / "catalog.json").read_bytes()
    assert b'"versions"' not in before
    assert verify(folder).shards_rebuilt == 1
    assert replay(folder).episodes == 2
    (report,) = migrate(folder)
    assert report.already and (folder / "catalog.json").read_bytes() == before


def test_migrate_keeps_the_record(built, tmp_path):
    """The previous release's unsealed manifest, with a record: `catalog migrate` seals it as found."""
    folder = tmp_path / SLICE
    shutil.copytree(built, folder)
    path = folder / "catalog.json"
    data = json.loads(path.read_text())
    versions = data[VERSIONS_KEY]
    del data[SEAL_KEY]
    path.write_text(json.dumps(data, sort_keys=True, indent=2) + "\n")
    (report,) = migrate(folder)
    assert report.sealed
    again = json.loads(path.read_text())
    assert again[VERSIONS_KEY] == versions == installed_versions() and again[SEAL_KEY] == seal_of(again)
