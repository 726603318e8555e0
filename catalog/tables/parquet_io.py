"""The shard tables in Parquet: building them from episodes, writing them
byte-for-byte reproducibly, and reading them back with schema checks.

Every writer option that affects the bytes is pinned in :func:`writer_options`:
format version 2.6, data pages v1, compliant nested types, the Arrow schema stored,
zstd level :data:`ZSTD_LEVEL` for every column except the already-compressed
``image`` (stored uncompressed), dictionary encoding only for the low-cardinality
string columns, statistics only for the scalar columns (none for images, lists or
free text), plain encoding (no byte-stream-split, for the widest reader support),
page CRC32 checksums on, the page index written (its offset index lets a remote reader
find the page holding any row's image from the footer alone) and no bloom filters,
data pages closed after the first :data:`WRITE_BATCH_SIZE`-row batch that passes
:data:`DATA_PAGE_SIZE` bytes (so an image page holds about eight 224 px JPEGs, ~40 kB:
what a remote reader fetches for one image), a fixed dictionary limit, the sort order declared, and row groups of exactly
:data:`ROW_GROUP_ROWS` rows (only the last one shorter, whatever the number of
:meth:`TableWriter.write` calls). The key-value metadata holds only the Arrow
schema, ``dyana.table`` and ``dyana.schema_version``.

Not pinnable: pyarrow writes ``created_by = "parquet-cpp-arrow version X.Y.Z"``
into the footer and offers no option to set it, and the zstd bytes come from the
zstd library bundled in the pyarrow wheel. The bytes therefore depend on the
pyarrow version, which ``.ci/constraints.txt`` pins and every ``catalog.json`` records
(:mod:`catalog.store.versions`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from catalog.store.storage import is_remote, open_binary
from schemas.errors import ShardError
from schemas.frames import EpisodeFrames
from schemas.runs import is_run
from schemas.scene import PHASES
from schemas.spec import EpisodeSpec
from schemas.tables import (
    ARRAY_WIDTHS,
    EPISODES_SCHEMA,
    FRAMES_SCHEMA,
    OBSTACLE_CLEARANCE,
    OBSTACLE_FRAMES_SCHEMA,
    ROLLOUT_EPISODES_SCHEMA,
    STATE_COLUMNS,
)
from schemas.versions import FPS, SCHEMA_VERSION

#: Table kinds and their contract schemas.
SCHEMAS: dict[str, pa.Schema] = {
    "frames": FRAMES_SCHEMA,
    "obstacle_frames": OBSTACLE_FRAMES_SCHEMA,
    "episodes": EPISODES_SCHEMA,
    "rollout_episodes": ROLLOUT_EPISODES_SCHEMA,
}
ROW_GROUP_ROWS = 1024
ZSTD_LEVEL = 3
DATA_PAGE_SIZE = 32 * 1024
WRITE_BATCH_SIZE = 8
DICTIONARY_PAGE_LIMIT = 1 << 20
ROLLOUT_STATUSES = ("ok", "error")

_UNCOMPRESSED = {"image"}
_DICTIONARY = {
    "phase", "slice", "motion_type", "object", "hand", "rollout_format", "intercept_setting", "policy", "status"
}
_NO_STATISTICS = {"image", "tokens", "text", "spec", "error"}
_SORTED_BY = {"frames": ("episode_index", "frame_index"), "episodes": ("episode_index",)}
_SORTED_BY["rollout_episodes"] = _SORTED_BY["episodes"]
_SORTED_BY["obstacle_frames"] = _SORTED_BY["frames"]


def _leaf(field: pa.Field) -> str:
    """The Parquet column path of a field (compliant nested naming for lists)."""
    if pa.types.is_list(field.type) or pa.types.is_fixed_size_list(field.type):
        return f"{field.name}.list.element"
    return field.name


def writer_options(kind: str) -> dict[str, Any]:
    """The pinned ``pyarrow.parquet.ParquetWriter`` options of a table kind."""
    schema = _schema(kind)
    compression: dict[str, str] = {}
    levels: dict[str, int] = {}
    dictionary, statistics = [], []
    for field in schema:
        leaf = _leaf(field)
        if field.name in _UNCOMPRESSED:
            compression[leaf] = "NONE"
        else:
            compression[leaf] = "ZSTD"
            levels[leaf] = ZSTD_LEVEL
        if field.name in _DICTIONARY:
            dictionary.append(leaf)
        is_list = pa.types.is_fixed_size_list(field.type) or pa.types.is_list(field.type)
        if not is_list and field.name not in _NO_STATISTICS:
            statistics.append(leaf)
    return {
        "version": "2.6",
        "data_page_version": "1.0",
        "use_compliant_nested_type": True,
        "store_schema": True,
        "writer_engine_version": "V2",
        "compression": compression,
        "compression_level": levels,
        "use_dictionary": dictionary,
        "write_statistics": statistics,
        "use_byte_stream_split": False,
        "data_page_size": DATA_PAGE_SIZE,
        "write_batch_size": WRITE_BATCH_SIZE,
        "dictionary_pagesize_limit": DICTIONARY_PAGE_LIMIT,
        "write_page_index": True,
        "write_page_checksum": True,
        "use_content_defined_chunking": False,
        "sorting_columns": [pq.SortingColumn(schema.get_field_index(n)) for n in _SORTED_BY[kind]],
    }


def _schema(kind: str) -> pa.Schema:
    try:
        return SCHEMAS[kind]
    except KeyError:
        raise ValueError(f"unknown table kind {kind!r} (expected one of {sorted(SCHEMAS)})") from None


def _fixed_list(values: np.ndarray, width: int) -> pa.FixedSizeListArray:
    flat = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float32()), width)


def frames_table(
    episode_index: int, frames: EpisodeFrames, images: Sequence[bytes], fps: int = FPS, obstacles: bool = False
) -> pa.Table:
    """One row per frame of one episode, in the frames contract's schema (``obstacles``:
    with the ``obstacle_clearance`` column, +inf where the episode has no obstacle).

    ``timestamp`` is ``frame_index / fps`` computed per row (float64), never summed.
    Float arrays are stored as float32 (cast if given wider).
    """
    n = frames.num_frames
    if len(images) != n:
        raise ShardError(f"episode {episode_index}: {len(images)} images for {n} frames")
    for i, image in enumerate(images):
        if not isinstance(image, (bytes, bytearray, memoryview)) or len(image) == 0:
            raise ShardError(f"episode {episode_index}: image of frame {i} must be non-empty bytes")
    frame_index = np.arange(n, dtype=np.int32)
    columns: dict[str, pa.Array] = {
        "episode_index": pa.array(np.full(n, episode_index, dtype=np.int64)),
        "frame_index": pa.array(frame_index),
        "timestamp": pa.array(frame_index.astype(np.float64) / float(fps)),
        "phase": pa.array([PHASES[int(i)] for i in frames.phase], type=pa.string()),
        "image": pa.array([bytes(b) for b in images], type=pa.binary()),
    }
    for name in (*STATE_COLUMNS, "action"):
        columns[name] = _fixed_list(getattr(frames, name), ARRAY_WIDTHS[name])
    columns["fingertip_distance"] = pa.array(np.asarray(frames.fingertip_distance, dtype=np.float32))
    schema = FRAMES_SCHEMA
    if obstacles:
        clearance = frames.obstacle_clearance
        values = np.full(n, np.inf, dtype=np.float32) if clearance is None else np.asarray(clearance, dtype=np.float32)
        columns[OBSTACLE_CLEARANCE] = pa.array(values)
        schema = OBSTACLE_FRAMES_SCHEMA
    elif frames.obstacle_clearance is not None:
        raise ShardError(f"episode {episode_index}: has obstacles but the build's frames table has no clearance column")
    return pa.Table.from_arrays([columns[f.name] for f in schema], schema=schema)


def episode_row(
    spec: EpisodeSpec,
    grasp_angles: np.ndarray,
    *,
    policy: str | None = None,
    status: str | None = None,
    error: str | None = None,
    privileged: bool = False,
) -> dict[str, Any]:
    """One episodes-table row as a dict of Python values; rollouts pass ``policy`` and
    ``status`` (and ``privileged``: whether the policy received the ground-truth spec)."""
    angles = np.asarray(grasp_angles, dtype=np.float32)
    if angles.shape != (ARRAY_WIDTHS["joint_angles"],):
        raise ShardError(f"episode {spec.episode_index}: grasp_angles must have shape (15,), got {angles.shape}")
    row: dict[str, Any] = {
        "episode_index": spec.episode_index,
        "episode_id": spec.episode_id,
        "slice": spec.slice,
        "motion_type": spec.motion_type,
        "tokens": spec.motion.to_json(),
        "object": spec.object,
        "object_size": spec.object_size,
        "rolling": spec.rolling,
        "hand": spec.hand,
        "rollout_format": spec.rollout_format,
        "intercept_setting": spec.intercept_setting,
        "intercept_time_s": spec.intercept_time_s,
        "observe_frames": spec.observe_frames,
        "intercept_frame": spec.intercept_frame,
        "num_frames": spec.num_frames,
        "grasp_angles": angles,
        "seed": spec.seed,
        "spec_hash": spec.spec_hash,
        "text": spec.text,
        "spec": spec.to_json(),
    }
    if policy is None and status is None and error is None:
        return row
    if not isinstance(policy, str) or not policy:
        raise ShardError(f"episode {spec.episode_index}: a rollout needs a policy name, got {policy!r}")
    if status not in ROLLOUT_STATUSES:
        raise ShardError(
            f"episode {spec.episode_index}: status must be one of {list(ROLLOUT_STATUSES)}, got {status!r}"
        )
    error = "" if error is None else error
    if not isinstance(error, str) or (status == "error") != bool(error):
        raise ShardError(
            f"episode {spec.episode_index}: error must be a non-empty reason exactly when status is 'error', "
            f"got status={status!r} error={error!r}"
        )
    if not isinstance(privileged, bool):
        raise ShardError(f"episode {spec.episode_index}: privileged must be a bool, got {privileged!r}")
    row.update(policy=policy, privileged=privileged, status=status, error=error)
    return row


def episodes_table(rows: Sequence[Mapping[str, Any]], rollout: bool = False) -> pa.Table:
    """Rows from :func:`episode_row` as an episodes (or rollout episodes) table."""
    schema = ROLLOUT_EPISODES_SCHEMA if rollout else EPISODES_SCHEMA
    arrays = []
    for field in schema:
        try:
            values = [row[field.name] for row in rows]
        except KeyError:
            raise ShardError(f"episodes row is missing column {field.name!r}") from None
        if pa.types.is_fixed_size_list(field.type):
            width = field.type.list_size
            stacked = np.stack(values) if values else np.zeros((0, width), np.float32)
            arrays.append(_fixed_list(stacked, width))
        else:
            arrays.append(pa.array(values, type=field.type))
    return pa.Table.from_arrays(arrays, schema=schema)


class TableWriter:
    """Streams tables of one kind into a Parquet file in fixed-size row groups.

    Rows are buffered until :data:`ROW_GROUP_ROWS` are available, so the file layout
    depends only on the sequence of rows, not on how they were batched.
    """

    def __init__(self, where: str | os.PathLike[str], kind: str) -> None:
        self.kind = kind
        self.schema = _schema(kind)
        file_schema = self.schema.with_metadata({"dyana.table": kind, "dyana.schema_version": SCHEMA_VERSION})
        self._writer = pq.ParquetWriter(os.fspath(where), file_schema, **writer_options(kind))
        self._pending: list[pa.Table] = []
        self._pending_rows = 0
        self.rows = 0

    def write(self, table: pa.Table) -> None:
        if not table.schema.equals(self.schema):
            raise ShardError(f"{self.kind} table has schema {table.schema}, expected {self.schema}")
        self._pending.append(table)
        self._pending_rows += table.num_rows
        self.rows += table.num_rows
        if self._pending_rows >= ROW_GROUP_ROWS:
            self._flush(final=False)

    def _flush(self, final: bool) -> None:
        if not self._pending_rows:
            return
        table = pa.concat_tables(self._pending)
        full = table.num_rows if final else table.num_rows - table.num_rows % ROW_GROUP_ROWS
        for start in range(0, full, ROW_GROUP_ROWS):
            group = table.slice(start, min(ROW_GROUP_ROWS, full - start)).combine_chunks()
            self._writer.write_table(group, row_group_size=ROW_GROUP_ROWS)
        rest = table.slice(full)
        self._pending = [rest] if rest.num_rows else []
        self._pending_rows = rest.num_rows

    def close(self) -> None:
        """Write the last (short) row group and the footer."""
        self._flush(final=True)
        self._writer.close()

    def abort(self) -> None:
        """Close the underlying file without completing it (the caller deletes it)."""
        self._pending, self._pending_rows = [], 0
        try:
            self._writer.close()
        except Exception:  # the file is discarded anyway
            pass


def write_table(path: str | os.PathLike[str], table: pa.Table, kind: str) -> None:
    """Write one whole table with the pinned options (not atomic: see ``catalog.store.atomic``)."""
    writer = TableWriter(path, kind)
    try:
        writer.write(table)
    except BaseException:
        writer.abort()
        raise
    writer.close()


# --- reading -------------------------------------------------------------------------


def open_parquet(path: str | os.PathLike[str]) -> pq.ParquetFile:
    """Open a Parquet file (footer parsed, page checksums verified on read), or ShardError."""
    try:
        source = open_binary(path) if is_remote(path) else os.fspath(path)
        return pq.ParquetFile(source, page_checksum_verification=True)
    except FileNotFoundError:
        raise ShardError(f"{path}: file is missing") from None
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise ShardError(f"{path}: not a readable Parquet file (truncated or corrupt): {exc}") from None


def table_kind(parquet: pq.ParquetFile) -> str:
    """``frames``, ``episodes`` or ``rollout_episodes``, judged from the columns."""
    names = set(parquet.schema_arrow.names)
    if "frame_index" in names:
        return "frames"
    return "rollout_episodes" if is_run(names) else "episodes"


def _contract(kind: str, parquet: pq.ParquetFile) -> pa.Schema:
    """A file's contract schema: a frames file with the clearance column is an obstacle build's."""
    if kind == "frames" and OBSTACLE_CLEARANCE in parquet.schema_arrow.names:
        return OBSTACLE_FRAMES_SCHEMA
    return _schema(kind)


def check_columns(
    path: str | os.PathLike[str], parquet: pq.ParquetFile, kind: str, columns: Sequence[str] | None
) -> list[str]:
    """The requested columns (all of the contract's by default), each present with its contract type."""
    contract = _contract(kind, parquet)
    wanted = list(contract.names) if columns is None else list(columns)
    have = parquet.schema_arrow
    for name in wanted:
        if contract.get_field_index(name) < 0:
            raise ShardError(f"{path}: {name!r} is not a column of the {kind} table")
        index = have.get_field_index(name)
        if index < 0:
            raise ShardError(f"{path}: missing column {name!r}")
        expected = contract.field(name).type
        if not have.field(index).type.equals(expected):
            found = have.field(index).type
            raise ShardError(f"{path}: column {name!r} has type {found}, expected {expected}")
    return wanted


def _read(path: str | os.PathLike[str], kinds: tuple[str, ...], columns: Sequence[str] | None) -> pa.Table:
    with open_parquet(path) as parquet:
        kind = table_kind(parquet)
        if kind not in kinds:
            expected = " or ".join(repr(k) for k in kinds)
            raise ShardError(f"{path}: table kind is {kind!r}, expected {expected}")
        wanted = check_columns(path, parquet, kind, columns)
        contract = _contract(kind, parquet)
        try:
            table = parquet.read(columns=wanted)
        except (pa.ArrowException, OSError, ValueError) as exc:
            raise ShardError(f"{path}: corrupt Parquet data: {exc}") from None
    for name in wanted:
        nulls = table.column(name).null_count
        if nulls:
            raise ShardError(f"{path}: column {name!r} holds {nulls} null value(s) (the contract has none)")
    return table.select(wanted).cast(pa.schema([contract.field(name) for name in wanted]))


def read_frames(path: str | os.PathLike[str], columns: Sequence[str] | None = None) -> pa.Table:
    """Read a frames file (selected columns, contract order if ``None``); ShardError names the file."""
    return _read(path, ("frames",), columns)


def read_episodes(path: str | os.PathLike[str], columns: Sequence[str] | None = None) -> pa.Table:
    """Read an episodes file of a built slice or of rollouts (then with policy/status/error)."""
    return _read(path, ("episodes", "rollout_episodes"), columns)


def check_parquet(path: str | os.PathLike[str], kind: str, rows: int | None = None) -> None:
    """Cheap structural check from the footer: readable, of ``kind`` with every column, ``rows`` rows."""
    with open_parquet(path) as parquet:
        found = table_kind(parquet)
        if found != kind:
            raise ShardError(f"{path}: table kind is {found!r}, expected {kind!r}")
        check_columns(path, parquet, kind, None)
        if rows is not None and parquet.metadata.num_rows != rows:
            raise ShardError(f"{path}: has {parquet.metadata.num_rows} rows, expected {rows}")


def column_to_numpy(column: pa.ChunkedArray | pa.Array) -> np.ndarray:
    """A fixed-size-list column as an ``(n, width)`` array; a scalar column as ``(n,)``."""
    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    if pa.types.is_fixed_size_list(column.type):
        width = column.type.list_size
        return column.flatten().to_numpy(zero_copy_only=False).reshape(-1, width)
    return column.to_numpy(zero_copy_only=False)
