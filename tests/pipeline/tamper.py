"""Tampering helpers for the replay tests: rewrite a shard file the way only replay
can notice (the manifest's hashes and seal are updated to match, with Dyana's own writer)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa

from catalog.store.hashing import sha256_file
from catalog.store.manifest import SEAL_KEY, Manifest, load_manifest, write_manifest
from catalog.store.records import FileRecord, ShardRecord
from catalog.tables.parquet_io import read_episodes, read_frames, write_table


def rewrite_frames(folder: Path, shard_index: int, mutate: Callable[[pa.Table], pa.Table]) -> ShardRecord:
    """Rewrite one shard's frames file through ``mutate`` with the pinned writer options,
    then update its sha256/size and the manifest hash, so integrity checks still pass."""
    path = folder / load_manifest(folder).shards[shard_index].files["frames"].path
    write_table(path, mutate(read_frames(path)), "frames")
    return rehash(folder, shard_index, "frames")


def rewrite_episodes(folder: Path, shard_index: int, mutate: Callable[[pa.Table], pa.Table]) -> ShardRecord:
    """Rewrite one shard's episodes table through ``mutate`` (the rollout writer's options),
    then re-hash and re-seal the manifest like :func:`rewrite_frames`."""
    path = folder / load_manifest(folder).shards[shard_index].files["episodes"].path
    write_table(path, mutate(read_episodes(path)), "rollout_episodes")
    return rehash(folder, shard_index, "episodes")


def set_column(table: pa.Table, column: str, row: int, value: object) -> pa.Table:
    """``table`` with one value of a column replaced."""
    values = table.column(column).to_pylist()
    values[row] = value
    index = table.schema.get_field_index(column)
    return table.set_column(index, table.schema.field(column), pa.array(values, type=table.schema.field(column).type))


def reseal(folder: Path, **changes: object) -> Manifest:
    """Rewrite the manifest with Dyana's writer: ``changes`` to its extra keys (``audit``:
    the trail records) and every other key as it was; hash and seal recomputed."""
    manifest = load_manifest(folder)
    audit = changes.pop("audit", manifest.audit)
    updated = Manifest.create(manifest.slice, manifest.seed, manifest.settings, manifest.shards, code=manifest.code,
                              extra={**manifest.extra, **changes}, stats=manifest.stats, audit=audit,
                              versions=manifest.versions)
    write_manifest(folder, updated)
    return updated


def copy_of(folder: Path, parent: Path) -> Path:
    """A copy of a module-scoped folder for one test to tamper with: ``parent/run``."""
    target = parent / "run"
    shutil.copytree(folder, target)
    return target


def unseal(folder: Path) -> None:
    """``folder``'s catalog.json as the previous release wrote it: without its seal."""
    path = folder / "catalog.json"
    data = json.loads(path.read_text())
    del data[SEAL_KEY]
    path.write_text(json.dumps(data, sort_keys=True, indent=2) + "\n")


def rehash(folder: Path, shard_index: int, kind: str) -> ShardRecord:
    """Record a rewritten file's new sha256 and size (and the new slice hash) in the manifest."""
    manifest = load_manifest(folder)
    shard = manifest.shards[shard_index]
    record = shard.files[kind]
    path = folder / record.path
    files = dict(shard.files)
    files[kind] = FileRecord(record.path, sha256_file(path), path.stat().st_size)
    shards = list(manifest.shards)
    shards[shard_index] = ShardRecord(shard.episodes, shard.frames, files)
    updated = Manifest.create(
        manifest.slice, manifest.seed, manifest.settings, shards, code=manifest.code, extra=manifest.extra,
        stats=manifest.stats, audit=manifest.audit, versions=manifest.versions,
    )
    write_manifest(folder, updated)
    return shards[shard_index]


def set_state_value(table: pa.Table, episode: int, frame: int, column: str, element: int, delta: float) -> pa.Table:
    """``table`` with one float32 element of one frame's array nudged by ``delta``."""
    rows = np.flatnonzero(
        (table.column("episode_index").to_numpy() == episode) & (table.column("frame_index").to_numpy() == frame)
    )
    assert rows.size == 1, (episode, frame)
    col = table.column(column).combine_chunks()
    width = col.type.list_size
    values = col.flatten().to_numpy(zero_copy_only=False).reshape(-1, width).copy()
    values[rows[0], element] += np.float32(delta)
    new = pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1), type=pa.float32()), width)
    return table.set_column(table.schema.get_field_index(column), table.schema.field(column), new)


def flip_image_byte(table: pa.Table, episode: int, frame: int) -> pa.Table:
    """``table`` with one byte in the middle of one frame's JPEG changed."""
    rows = np.flatnonzero(
        (table.column("episode_index").to_numpy() == episode) & (table.column("frame_index").to_numpy() == frame)
    )
    images = table.column("image").to_pylist()
    data = bytearray(images[rows[0]])
    data[len(data) // 2] ^= 0x01
    images[rows[0]] = bytes(data)
    index = table.schema.get_field_index("image")
    return table.set_column(index, table.schema.field("image"), pa.array(images, type=pa.binary()))
