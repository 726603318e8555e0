"""The library versions a manifest records (``versions``): what is recorded, how it is
compared with this installation, and that folders without the record still load."""

from __future__ import annotations

import json
import platform

import numpy as np
import pyarrow as pa
import pytest

from catalog.store.manifest import SEAL_KEY, Manifest, load_manifest, write_manifest
from catalog.store.versions import (
    BYTE_DISTRIBUTIONS,
    VERSIONS_KEY,
    checked_versions,
    installed_versions,
    mismatch_note,
    version_differences,
)
from schemas.errors import ShardError

from .conftest import CODE, write_slice


def test_installed_versions_are_this_installations():
    found = installed_versions()
    assert list(found) == ["python", *BYTE_DISTRIBUTIONS]
    assert found["python"] == platform.python_version()
    assert found["numpy"] == np.__version__ and found["pyarrow"] == pa.__version__


def test_differences_name_each_differing_version_and_nothing_when_equal():
    recorded = {"python": "3.11.7", "pyarrow": "21.0.0", "numpy": "2.1.0", "simplejpeg": None}
    assert version_differences(recorded, dict(recorded)) == []
    assert version_differences(recorded, {**recorded, "pyarrow": "22.0.0", "extra": "1"}) == [
        "recorded pyarrow 21.0.0, installed 22.0.0"]
    assert version_differences(recorded, {"python": "3.11.7", "pyarrow": "21.0.0", "simplejpeg": "1.8.1"}) == [
        "recorded numpy 2.1.0, installed (none)", "recorded simplejpeg (none), installed 1.8.1"]
    assert mismatch_note(recorded, dict(recorded)) == ""
    assert mismatch_note(recorded, {**recorded, "pyarrow": "22.0.0"}) == "; recorded pyarrow 21.0.0, installed 22.0.0"
    assert "records no library versions" in mismatch_note(None)


@pytest.mark.parametrize("value, needle", [
    ([], "versions must be a non-empty object"),
    ({}, "versions must be a non-empty object"),
    ({"numpy": 2}, "versions[numpy] must be a version string or null, got 2"),
    ({"numpy": ""}, "versions[numpy] must be a version string or null"),
    ({"": "1.0"}, "must be a version string or null"),
])
def test_a_malformed_record_is_refused_naming_it(value, needle):
    with pytest.raises(ShardError) as info:
        checked_versions(value)
    assert needle in str(info.value)


def test_a_build_records_its_versions_outside_the_slice_hash(tmp_path):
    manifest = write_slice(tmp_path / "a")
    recorded = Manifest.create(manifest.slice, manifest.seed, manifest.settings, manifest.shards, code=CODE,
                               stats=manifest.stats, versions=installed_versions())
    other = Manifest.create(manifest.slice, manifest.seed, manifest.settings, manifest.shards, code=CODE,
                            stats=manifest.stats, versions={**installed_versions(), "pyarrow": "1.0.0"})
    assert recorded.hash == other.hash == manifest.hash  # the slice hash covers the data, not the libraries
    data = recorded.to_dict()
    assert data[VERSIONS_KEY] == installed_versions() and VERSIONS_KEY in data[SEAL_KEY]
    write_manifest(tmp_path / "a", recorded)
    assert load_manifest(tmp_path / "a").versions == installed_versions()


def test_an_edited_record_is_refused_by_the_seal(tmp_path):
    manifest = write_slice(tmp_path / "a")
    write_manifest(tmp_path / "a", Manifest.create(manifest.slice, manifest.seed, manifest.settings, manifest.shards,
                                                   code=CODE, versions={"python": "3.11.7", "pyarrow": "21.0.0"}))
    path = tmp_path / "a" / "catalog.json"
    data = json.loads(path.read_text())
    data[VERSIONS_KEY]["pyarrow"] = "22.0.0"
    path.write_text(json.dumps(data))
    with pytest.raises(ShardError, match="edited after it was written .changed: versions;"):
        load_manifest(tmp_path / "a")
def test_a_manifest_written_before_the_record_still_loads(tmp_path):
    """A folder of the current dataset version written before manifests recorded versions
    (sealed, without the key) loads and says it records none."""
    write_slice(tmp_path / "old")
    data = json.loads((tmp_path / "old" / "catalog.json").read_text())
    assert VERSIONS_KEY not in data and VERSIONS_KEY not in data[SEAL_KEY]
    assert load_manifest(tmp_path / "old").versions is None
