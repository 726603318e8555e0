"""Normalisation statistics of a folder's states and actions, kept in ``stats.json``
beside ``catalog.json``.

For every float column of the frames table (the states of
``schemas.tables.STATE_COLUMNS``, ``fingertip_distance`` and ``action``): ``count``,
``mean``, ``std`` (population, ddof 0), ``min`` and ``max``, element by element,
over every frame of the folder. They are computed from those columns only (the
``image`` column is never read, no image is decoded), in float64, shard by shard: each
shard's :class:`PartialStats` (count, mean, sum of squared deviations, min, max: exactly
mergeable, no quantiles), merged in manifest order with the pairwise (Chan et al.) update,
so the same folder always gives the same numbers. A job's worker computes its shard's
partial statistics from the frames file it just wrote and returns them with the shard's
record (the resume state keeps them), so the driver merges them without reading a shard
again (:func:`merge_partials`); the numbers, and ``stats.json``'s bytes, are the same as
:func:`compute_stats` reading the finished folder.

Every job writes ``stats.json`` (canonical JSON: sorted keys, 2-space indent,
trailing newline) before ``catalog.json``, which lists it with its sha256 and size and
covers that sha256 with its hash: an edited file is refused by every reader
(:class:`~schemas.errors.ShardHashMismatch`), never served. A folder whose manifest
lists no statistics (written by other tools) gets them computed in memory, unsaved.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from catalog.store.atomic import atomic_write_text
from catalog.store.hashing import sha256_file
from catalog.store.manifest import Manifest, load_manifest
from catalog.store.records import FileRecord, ShardRecord
from catalog.store.storage import as_location
from catalog.tables.parquet_io import column_to_numpy
from catalog.tables.reader import ShardReader, check_file, open_folder
from schemas.errors import ShardError
from schemas.tables import ARRAY_WIDTHS, STATE_COLUMNS

STATS_NAME = "stats.json"
STATS_VERSION = 2
#: The columns described, in frames-table order; ``fingertip_distance`` is a scalar (shape ()).
STATS_COLUMNS = (*STATE_COLUMNS, "action", "fingertip_distance")
SHAPES = {name: (ARRAY_WIDTHS[name],) for name in (*STATE_COLUMNS, "action")} | {"fingertip_distance": ()}
_FIELDS = ("mean", "std", "min", "max")


@dataclass(frozen=True)
class ColumnStats:
    """Element-wise statistics of one column (float64 arrays of the column's per-frame shape)."""

    count: int
    mean: np.ndarray
    std: np.ndarray
    min: np.ndarray
    max: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"count": self.count}
        for name in _FIELDS:
            out[name] = getattr(self, name).tolist()
        return out


@dataclass(frozen=True)
class Stats:
    """Statistics of every column in :data:`STATS_COLUMNS`; ``stats["action"].mean``."""

    frames: int
    columns: Mapping[str, ColumnStats]

    def __post_init__(self) -> None:
        object.__setattr__(self, "columns", MappingProxyType(dict(self.columns)))

    def __getitem__(self, name: str) -> ColumnStats:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"no statistics for {name!r} (columns: {list(self.columns)})") from None

    def to_dict(self) -> dict[str, Any]:
        return {
            "version": STATS_VERSION,
            "frames": self.frames,
            "columns": {name: self.columns[name].to_dict() for name in STATS_COLUMNS},
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, indent=2, ensure_ascii=True, allow_nan=False) + "\n"

    @classmethod
    def from_dict(cls, data: Any) -> Stats:
        """Parse and validate; ValueError naming the bad key."""
        if not isinstance(data, dict) or data.get("version") != STATS_VERSION:
            raise ValueError(f"not a version-{STATS_VERSION} stats object")
        frames = data.get("frames")
        if isinstance(frames, bool) or not isinstance(frames, int) or frames < 0:
            raise ValueError(f"frames must be an integer >= 0, got {frames!r}")
        columns = data.get("columns")
        if not isinstance(columns, dict) or set(columns) != set(STATS_COLUMNS):
            raise ValueError(f"columns must be exactly {list(STATS_COLUMNS)}")
        parsed = {}
        for name in STATS_COLUMNS:
            entry = columns[name]
            if not isinstance(entry, dict) or entry.get("count") != frames:
                raise ValueError(f"columns.{name}.count must equal frames ({frames})")
            values = {}
            for key in _FIELDS:
                try:
                    array = np.asarray(entry.get(key), dtype=np.float64)
                except (TypeError, ValueError):
                    raise ValueError(f"columns.{name}.{key} is not numeric") from None
                if array.shape != SHAPES[name] or (frames and not np.all(np.isfinite(array))):
                    raise ValueError(f"columns.{name}.{key} must be finite of shape {SHAPES[name]}")
                values[key] = array
            parsed[name] = ColumnStats(frames, **values)
        return cls(frames, parsed)


class _Accumulator:
    """count, mean, M2 (sum of squared deviations), min, max of one column, merged chunk by chunk."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.count = 0
        self.mean = np.zeros(shape)
        self.m2 = np.zeros(shape)
        self.min = np.full(shape, np.inf)
        self.max = np.full(shape, -np.inf)

    def merge(self, n: int, mean: np.ndarray, m2: np.ndarray, low: np.ndarray, high: np.ndarray) -> None:
        total = self.count + n
        delta = mean - self.mean
        self.mean = self.mean + delta * (n / total)
        self.m2 = self.m2 + m2 + delta**2 * (self.count * n / total)
        self.min = np.minimum(self.min, low)
        self.max = np.maximum(self.max, high)
        self.count = total

    def result(self) -> ColumnStats:
        if self.count == 0:
            zero = np.zeros_like(self.mean)
            return ColumnStats(0, zero, zero.copy(), zero.copy(), zero.copy())
        std = np.sqrt(self.m2 / self.count)
        return ColumnStats(self.count, self.mean.copy(), std, self.min.copy(), self.max.copy())


@dataclass(frozen=True)
class PartialStats:
    """One shard's statistics in mergeable form: its frame count and, per column (none when
    it has no frames), float64 ``(mean, m2, min, max)`` of its frames; merging them in
    shard order (:func:`merge_partials`) gives exactly what one pass over the folder does."""

    frames: int
    columns: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON values (Python floats: JSON keeps every float64 bit)."""
        return {"frames": self.frames,
                "columns": {name: {key: value.tolist() for key, value in zip(_PARTS, parts, strict=True)}
                            for name, parts in self.columns.items()}}

    @classmethod
    def from_dict(cls, data: Any) -> PartialStats:
        """Parse and validate; ValueError naming the bad key."""
        frames = data.get("frames") if isinstance(data, dict) else None
        if isinstance(frames, bool) or not isinstance(frames, int) or frames < 0:
            raise ValueError(f"frames must be an integer >= 0, got {frames!r}")
        columns = data.get("columns")
        if not isinstance(columns, dict) or set(columns) != (set(STATS_COLUMNS) if frames else set()):
            raise ValueError("columns must be every statistics column (none for a shard without frames)")
        parsed = {}
        for name, entry in columns.items():
            if not isinstance(entry, dict):
                raise ValueError(f"columns.{name} must be an object")
            values = []
            for key in _PARTS:
                try:
                    array = np.asarray(entry.get(key), dtype=np.float64)
                except (TypeError, ValueError):
                    raise ValueError(f"columns.{name}.{key} is not numeric") from None
                if array.shape != SHAPES[name] or not np.all(np.isfinite(array)):
                    raise ValueError(f"columns.{name}.{key} must be finite of shape {SHAPES[name]}")
                values.append(array)
            parsed[name] = (values[0], values[1], values[2], values[3])
        return cls(frames, parsed)


_PARTS = ("mean", "m2", "min", "max")


def shard_partial(shard: ShardReader) -> PartialStats:
    """The partial statistics of one shard's frames (ShardError naming the file when a column
    holds a non-finite value)."""
    path = shard.path("frames")
    table = shard.frames(list(STATS_COLUMNS))
    columns = {}
    for name in STATS_COLUMNS if table.num_rows else ():
        values = column_to_numpy(table.column(name))
        if not np.isfinite(values).all():
            raise ShardError(f"{path}: column {name!r} holds non-finite values (NaN or infinity)")
        data = values.astype(np.float64)
        mean = data.mean(axis=0)
        columns[name] = (mean, ((data - mean) ** 2).sum(axis=0), data.min(axis=0), data.max(axis=0))
    return PartialStats(table.num_rows, columns)


def written_partial(folder: str | os.PathLike[str], record: ShardRecord) -> dict[str, Any] | None:
    """A task's partial statistics of the shard it just wrote into ``folder`` (as a dict);
    None when they cannot be computed (a non-finite value): the driver then reads the shard
    where the job's output is and names the file in its refusal, as it always did."""
    try:
        return shard_partial(ShardReader(as_location(folder), record, rollout=False, verify="size")).to_dict()
    except ShardError:
        return None


def merge_partials(parts: Sequence[PartialStats]) -> Stats:
    """The statistics of the shards whose partial statistics ``parts`` are, in shard order."""
    accumulators = {name: _Accumulator(SHAPES[name]) for name in STATS_COLUMNS}
    for part in parts:
        for name in STATS_COLUMNS if part.frames else ():
            accumulators[name].merge(part.frames, *part.columns[name])
    return Stats(sum(p.frames for p in parts), {name: accumulators[name].result() for name in STATS_COLUMNS})


def compute_stats(
    directory: str | os.PathLike[str], shards: Sequence[ShardRecord] | None = None, *, verify: bool = False
) -> Stats:
    """Statistics of every frame of a folder (or of the given ``shards`` of it, before its
    manifest exists), from the float columns of its frames files, checked as every reader
    checks them. ``verify`` also compares each frames file's sha256 (reading, not
    decoding, the image bytes); page checksums are verified either way."""
    root = as_location(directory)
    records = open_folder(root).manifest.shards if shards is None else tuple(shards)
    check = "sha256" if verify else "size"
    return merge_partials([shard_partial(ShardReader(root, record, rollout=False, verify=check)) for record in records])


def stats_path(directory: str | os.PathLike[str]) -> Path:
    return as_location(directory) / STATS_NAME


def write_stats(directory: str | os.PathLike[str], stats: Stats) -> FileRecord:
    """Write ``DIR/stats.json`` atomically; its record for the manifest."""
    path = atomic_write_text(stats_path(directory), stats.to_json())
    return FileRecord(STATS_NAME, sha256_file(path), path.stat().st_size)


def load_stats(directory: str | os.PathLike[str], manifest: Manifest | None = None, *, verify: bool = False) -> Stats:
    """The folder's statistics: ``stats.json`` once its size and sha256 match the manifest's
    record (else a typed ShardError naming it), or computed in memory when the manifest
    lists none."""
    root = as_location(directory)
    manifest = load_manifest(root) if manifest is None else manifest
    if manifest.stats is None:
        return compute_stats(root, manifest.shards, verify=verify)
    path = check_file(root, manifest.stats, "sha256")
    try:
        stats = Stats.from_dict(json.loads(path.read_text(encoding="utf-8")))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ShardError(f"{path}: not valid statistics: {exc}") from None
    if stats.frames != manifest.frames:
        raise ShardError(f"{path}: describes {stats.frames} frames, catalog.json lists {manifest.frames}")
    return stats


def combine(parts: Sequence[Stats]) -> Stats:
    """Statistics of the union of several folders' frames (pooled exactly from the parts)."""
    if len(parts) == 1:
        return parts[0]
    columns = {}
    for name in STATS_COLUMNS:
        total = _Accumulator(SHAPES[name])
        for part in parts:
            column = part[name]
            if column.count:
                total.merge(column.count, column.mean, column.std**2 * column.count, column.min, column.max)
        columns[name] = total.result()
    return Stats(sum(p.frames for p in parts), columns)


__all__ = [
    "STATS_COLUMNS",
    "STATS_NAME",
    "ColumnStats",
    "PartialStats",
    "Stats",
    "combine",
    "compute_stats",
    "load_stats",
    "merge_partials",
    "shard_partial",
    "write_stats",
    "written_partial",
]
