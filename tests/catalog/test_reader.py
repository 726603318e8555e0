"""The one shard reader (catalog.tables.reader): each check raises its typed error naming the file."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest

from catalog.store.manifest import Manifest, load_manifest, write_manifest
from catalog.tables.parquet_io import read_episodes, read_frames, write_table
from catalog.tables.reader import open_folder
from schemas.errors import (
    DuplicateEpisode,
    FrameNumberingError,
    SettingsMismatch,
    ShardContentError,
    ShardError,
    ShardHashMismatch,
    ShardMissing,
    ShardSizeMismatch,
)
from tests.pipeline.tamper import rehash


def _path(folder: Path, kind: str, shard: int = 0) -> Path:
    return folder / load_manifest(folder).shards[shard].files[kind].path


def _read_all(folder: Path, verify: str = "size") -> None:
    reader = open_folder(folder, verify=verify)
    for shard in reader:
        shard.frames(None, shard.episodes())


def test_an_intact_folder_reads_every_row(slice_dir):
    reader = open_folder(slice_dir, verify="sha256")
    assert reader.episodes(["num_frames"]).column("episode_index").to_pylist() == [0, 1, 2, 3, 4]
    assert reader.frames(["phase"]).num_rows == reader.manifest.frames
    row, frames = reader.episode(3)
    assert row["episode_index"] == 3 and frames.num_rows == row["num_frames"]


def test_a_missing_file(slice_dir):
    path = _path(slice_dir, "frames", 1)
    path.unlink()
    with pytest.raises(ShardMissing) as caught:
        _read_all(slice_dir)
    assert caught.value.path == str(path) and "file is missing" in str(caught.value)


def test_a_truncated_file(slice_dir):
    path = _path(slice_dir, "frames")
    size = path.stat().st_size
    path.write_bytes(path.read_bytes()[:-10])
    with pytest.raises(ShardSizeMismatch) as caught:
        _read_all(slice_dir)
    assert (caught.value.expected, caught.value.actual) == (size, size - 10)
    assert "truncated" in str(caught.value)


def test_changed_content_of_the_same_size_needs_the_hash(slice_dir):
    path = _path(slice_dir, "frames")
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(ShardHashMismatch, match="content changed"):
        _read_all(slice_dir, verify="sha256")


def test_a_duplicate_episode_is_named_as_a_duplicate(slice_dir):
    path = _path(slice_dir, "episodes")
    table = read_episodes(path)
    write_table(path, pa.concat_tables([table.slice(0, 1), table.slice(0, 1)]), "episodes")
    rehash(slice_dir, 0, "episodes")
    with pytest.raises(DuplicateEpisode, match="episode_index 0 is listed twice"):
        _read_all(slice_dir)


def test_frames_numbered_out_of_order(slice_dir):
    path = _path(slice_dir, "frames")
    table = read_frames(path)
    index = table.column("frame_index").to_pylist()
    index[1], index[2] = index[2], index[1]
    at = table.schema.get_field_index("frame_index")
    table = table.set_column(at, table.schema.field(at), pa.array(index, pa.int32()))
    write_table(path, table, "frames")
    rehash(slice_dir, 0, "frames")
    with pytest.raises(FrameNumberingError, match="row 1 of episode 0 has frame_index 2"):
        _read_all(slice_dir)


def test_a_frame_count_that_contradicts_the_episode_row(slice_dir):
    path = _path(slice_dir, "frames")
    table = read_frames(path)
    last = table.num_rows - 1
    write_table(path, table.slice(0, last), "frames")
    manifest = load_manifest(slice_dir)
    rehash(slice_dir, 0, "frames")
    assert load_manifest(slice_dir).shards[0].frames == manifest.shards[0].frames
    with pytest.raises(ShardContentError, match="rows, catalog.json says"):
        _read_all(slice_dir)


@pytest.mark.parametrize(
    "key, value",
    [("dataset_version", "0.9.0"), ("fps", 25), ("image_format", "png"), ("resolution", "224")],
)
def test_settings_a_reader_relies_on_are_checked(slice_dir, key, value):
    """A manifest claiming settings this code does not read (or another dataset version)
    is refused, even with a consistent hash."""
    manifest = load_manifest(slice_dir)
    settings = {**manifest.settings, key: value}
    write_manifest(
        slice_dir, Manifest.create(manifest.slice, manifest.seed, settings, manifest.shards, code=manifest.code)
    )
    with pytest.raises(SettingsMismatch) as caught:
        open_folder(slice_dir)
    assert caught.value.key == key and caught.value.actual == value


def test_what_the_caller_expects_is_checked(slice_dir):
    with pytest.raises(SettingsMismatch, match="settings resolution is 32, expected 112"):
        open_folder(slice_dir, expect={"resolution": 112})


def test_every_typed_error_is_a_shard_error():
    for kind in (ShardMissing, ShardSizeMismatch, ShardHashMismatch, DuplicateEpisode, FrameNumberingError, SettingsMismatch):
        assert issubclass(kind, ShardError)
