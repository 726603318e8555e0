"""The shards one process has open, for the dataloader: an LRU of loaded float matrices and
JPEG offsets, bounded by bytes, checked on first load (size, sha256 or page CRCs, the
index columns the dataset was opened with). See :mod:`catalog.loader.dataset` for the guarantees.
"""

from __future__ import annotations

import hashlib
import mmap
import os
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from catalog.loader.index import (
    FLOAT_COLUMNS,
    FLOAT_WIDTH,
    LAYOUT,
    SHARD_COLUMNS,
    ShardFile,
    index_digest,
)
from catalog.store.hashing import sha256_file
from catalog.store.storage import as_location, is_url, open_binary, reaching
from catalog.tables.pages import image_offsets, pread_into
from catalog.tables.parquet_io import check_columns, column_to_numpy, table_kind
from catalog.tables.remote_images import remote_images
from schemas.errors import (
    ShardError,
    ShardHashMismatch,
    ShardMissing,
    ShardSizeMismatch,
)
from schemas.scene import PHASES


class Descriptor:
    """Owns an open file descriptor and closes it when the last reference goes, so a
    shard evicted from the cache while an item is still being read from it keeps a
    valid descriptor (a closed number could be reused by another file)."""

    __slots__ = ("fd",)

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def __del__(self) -> None:
        try:
            os.close(self.fd)
        except Exception:  # already closed, or interpreter shutdown
            pass


class OpenShard:
    """A frames file in use: its descriptor, float columns, timestamps, phases and JPEG offsets."""

    __slots__ = ("path", "owner", "fd", "floats", "timestamp", "phase", "offsets", "lengths", "nbytes", "resolution")

    def __init__(self, path, owner, floats, timestamp, phase, offsets, lengths, resolution) -> None:
        self.path, self.owner, self.fd, self.resolution = path, owner, owner.fd, resolution
        self.floats, self.timestamp, self.phase = floats, timestamp, phase
        self.offsets, self.lengths = offsets, lengths
        # Python int lists (faster to index than numpy): about 72 bytes a row for the two.
        self.nbytes = floats.nbytes + timestamp.nbytes + phase.nbytes + 72 * len(floats)

    def jpeg(self, row: int) -> np.ndarray:
        """The JPEG bytes of ``row`` as a uint8 array: one ``preadv`` into a fresh buffer (about
        half the cost of ``os.pread``, which builds a bytes object), or a remote page's slice."""
        if self.fd is None:
            return np.frombuffer(self.owner.jpeg(row), dtype=np.uint8)
        length = self.lengths[row]
        data = np.empty(length, dtype=np.uint8)
        if pread_into(self.fd, data, self.offsets[row]) != length:
            raise ShardError(f"{self.path}: image of row {row} is cut off (file truncated while open)")
        return data


    def jpegs(self, lo: int, hi: int) -> list[np.ndarray]:
        """The JPEGs of rows ``lo ... hi - 1``: one ``preadv`` of the bytes that hold them
        (consecutive rows lie back to back, a page header at most between them), sliced."""
        if hi - lo < 2 or self.fd is None:
            return [self.jpeg(row) for row in range(lo, hi)]
        offsets, lengths = self.offsets, self.lengths
        start, stop = offsets[lo], offsets[hi - 1] + lengths[hi - 1]
        if stop - start > _SPAN:
            return [self.jpeg(row) for row in range(lo, hi)]
        data = np.empty(stop - start, dtype=np.uint8)
        if pread_into(self.fd, data, start) != stop - start:
            raise ShardError(f"{self.path}: images of rows {lo}-{hi - 1} are cut off (file truncated while open)")
        return [data[offsets[row] - start : offsets[row] - start + lengths[row]] for row in range(lo, hi)]


#: Longest span of bytes :meth:`OpenShard.jpegs` reads at once (else one read per row).
_SPAN = 1 << 20


def parquet_file(handle: Any, path: str, checksums: bool) -> pq.ParquetFile:
    """The Parquet reader of an open file or of bytes read from one (the very bytes that were
    hashed, even if the path has since been replaced), verifying page checksums if asked."""
    try:
        return pq.ParquetFile(handle, page_checksum_verification=checksums)
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise ShardError(f"{path}: not a readable Parquet file (truncated or corrupt): {exc}") from None


class ShardCache:
    """The shards one process has open, in an LRU bounded by bytes (and by open files)."""

    MAX_OPEN = 128

    def __init__(self, files: Sequence[ShardFile], verify: str, budget: int) -> None:
        self.pid = os.getpid()
        self.files = files
        self.verify = verify
        self.budget = budget
        self.cache: OrderedDict[int, OpenShard] = OrderedDict()
        self.bytes = 0
        self.verified: set[int] = set()
        self.last: tuple[int, OpenShard | None] = (-1, None)  # one tuple: swapped atomically between threads
        #: The last window's kept frames: (shard, first row, images of consecutive rows, the
        #: window's end row), for the next window of a sequential pass. Replaced whole,
        #: never mutated.
        self.recent: tuple[OpenShard | None, int, list[np.ndarray], int] = (None, 0, [], -2)

    def get(self, key: int) -> OpenShard:
        last_key, last = self.last
        if key == last_key and last is not None:
            return last
        shard = self.cache.get(key)
        if shard is None:
            shard = self._load(key)
            self.cache[key] = shard
            self.bytes += shard.nbytes
            while len(self.cache) > 1 and (self.bytes > self.budget or len(self.cache) > self.MAX_OPEN):
                _, old = self.cache.popitem(last=False)
                self.bytes -= old.nbytes
        else:
            self.cache.move_to_end(key)
        self.last = (key, shard)
        return shard

    def _load(self, key: int) -> OpenShard:
        record = self.files[key]
        if is_url(record.path):
            return self._load_remote(key)
        path = record.path
        try:
            owner = Descriptor(os.open(path, os.O_RDONLY))
        except FileNotFoundError:
            raise ShardMissing(path) from None
        except OSError as exc:
            raise ShardError(f"{path}: cannot open: {exc}") from None
        fd = owner.fd
        size = os.fstat(fd).st_size
        if size != record.size:
            raise ShardSizeMismatch(path, record.size, size)
        hashed = self.verify == "sha256" and key not in self.verified
        hasher = hashlib.sha256() if hashed else None
        # Every byte outside the image column lands in `kept`, an anonymous mapping of the
        # file's size (zeros elsewhere, never touched, so never resident), as it is hashed,
        # and the Parquet reader reads it from there: the very bytes that were hashed,
        # without a second read through a Python file object.
        kept = _footer(fd, path, size)
        with parquet_file(pa.BufferReader(pa.py_buffer(kept)), path, checksums=False) as parquet:
            metadata = parquet.metadata
        offsets, lengths = image_offsets(fd, path, metadata, check_crc=not hashed, hasher=hasher, keep=kept)
        if hasher is not None:
            digest = hasher.hexdigest()
            if digest != record.sha256:
                raise ShardHashMismatch(path, record.sha256, digest)
            self.verified.add(key)
        # Right after hashing every byte, page checksums are redundant; otherwise they are checked.
        with parquet_file(pa.BufferReader(pa.py_buffer(kept)), path, checksums=not hashed) as parquet:
            table = _index_columns(parquet, record)
        return _open_shard(record, owner, table, offsets, lengths)

    def _load_remote(self, key: int) -> OpenShard:
        """A remote frames file: size checked, float columns read, image pages located;
        its JPEGs are fetched page by page (:mod:`catalog.tables.remote_images`). The client's
        failures are one StorageError naming the file."""
        record = self.files[key]
        path = record.location if record.location is not None else as_location(record.path)  # options kept
        with reaching(record.path):
            return self._load_remote_file(key, record, path)

    def _load_remote_file(self, key: int, record: ShardFile, path: Path) -> OpenShard:
        try:
            size = path.stat().st_size
        except FileNotFoundError:
            raise ShardMissing(record.path) from None
        except OSError as exc:
            raise ShardError(f"{record.path}: cannot read: {exc}") from None
        if size != record.size:
            raise ShardSizeMismatch(record.path, record.size, size)
        if self.verify == "sha256" and key not in self.verified:
            digest = sha256_file(path)
            if digest != record.sha256:
                raise ShardHashMismatch(record.path, record.sha256, digest)
            self.verified.add(key)
        with open_binary(path) as handle, parquet_file(handle, record.path, checksums=True) as parquet:
            table = _index_columns(parquet, record)
            images = remote_images(path, record.path, parquet.metadata, size)
        return _open_shard(record, images, table, None, None)

    def close(self) -> None:
        """Forget every loaded shard (descriptors close as soon as no item is being read from them)."""
        self.cache.clear()
        self.bytes = 0
        self.last = (-1, None)
        self.recent = (None, 0, [], -2)



def _footer(fd: int, path: str, size: int) -> memoryview:
    """A zeroed anonymous mapping of ``size`` bytes with the file's Parquet footer read into its end."""
    tail = os.pread(fd, 8, max(0, size - 8))
    length = int.from_bytes(tail[:4], "little") + 8 if len(tail) == 8 and tail[4:] == b"PAR1" else size + 1
    if length + 4 > size:
        raise ShardError(f"{path}: not a readable Parquet file (truncated or corrupt): no footer")
    kept = memoryview(mmap.mmap(-1, size))
    if pread_into(fd, kept[size - length :], size - length) != length:
        raise ShardError(f"{path}: cut off while reading its footer (truncated)")
    return kept


def _index_columns(parquet: pq.ParquetFile, record: ShardFile) -> pa.Table:
    """The frames file's index and float columns, checked against the record and the contract."""
    path = record.path
    if table_kind(parquet) != "frames":
        raise ShardError(f"{path}: not a frames table")
    check_columns(path, parquet, "frames", SHARD_COLUMNS)
    if parquet.metadata.num_rows != record.frames:
        raise ShardError(f"{path}: has {parquet.metadata.num_rows} rows, catalog.json says {record.frames}")
    try:
        return parquet.read(columns=list(SHARD_COLUMNS), use_threads=False)
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise ShardError(f"{path}: corrupt Parquet data: {exc}") from None


def _open_shard(record: ShardFile, owner, table: pa.Table, offsets, lengths) -> OpenShard:
    path = record.path
    episode = column_to_numpy(table.column("episode_index"))
    frame = column_to_numpy(table.column("frame_index"))
    if index_digest(episode, frame) != record.index_digest:
        raise ShardError(f"{path}: episode_index/frame_index changed since the dataset was opened")
    for name in SHARD_COLUMNS:
        if table.column(name).null_count:
            raise ShardError(f"{path}: column {name!r} holds null values (the contract has none)")
    n = table.num_rows
    floats = np.empty((n, FLOAT_WIDTH), dtype=np.float32)
    for name in FLOAT_COLUMNS:
        start, stop = LAYOUT[name]
        floats[:, start:stop] = column_to_numpy(table.column(name)).reshape(n, stop - start)
    codes = pc.index_in(table.column("phase"), value_set=pa.array(PHASES))
    if codes.null_count:
        raise ShardError(f"{path}: phase holds a value outside {list(PHASES)}")
    phase = column_to_numpy(codes).astype(np.int8)
    timestamp = np.array(column_to_numpy(table.column("timestamp")), dtype=np.float64)
    return OpenShard(path, owner, floats, timestamp, phase, offsets, lengths, record.resolution)
