"""Where each JPEG lies in a frames file: the byte offset and length of every value
of the ``image`` column, found by walking its Parquet data pages.

The writer stores ``image`` uncompressed, PLAIN-encoded, as a required column in
data pages v1 (``catalog.tables.parquet_io.writer_options``). A page body is then just the
values, each a 4-byte little-endian length followed by the bytes, so once the
offsets are known a frame is one ``os.pread`` of its own bytes: random access
without reading a 1024-row row group per item.

Walking checks the layout (page type, encoding, value counts, every page ending
exactly where the next begins) and, with ``check_crc``, each page's CRC32 against
the checksum the writer stored in its header. Anything else raises ShardError
naming the file.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass

import pyarrow.parquet as pq

from catalog.tables.thrift import ThriftError, read_struct
from schemas.errors import ShardError

#: Parquet's ``PageType.DATA_PAGE`` and ``Encoding.PLAIN`` (parquet.thrift): a page header's field 1
#: is its type, field 5 the data page v1 header, whose field 2 is the encoding.
DATA_PAGE = 0
PLAIN = 0
_HEADER_READ = 256
_MAX_HEADER = 1 << 16
_LENGTH = struct.Struct("<I")
_BLOCK = 1 << 20


def _pread(source, length: int, offset: int) -> bytes:
    """``os.pread`` of a descriptor, or ``source.pread`` of a remote file (:class:`catalog.store.storage.RangeReader`)."""
    return os.pread(source, length, offset) if isinstance(source, int) else source.pread(length, offset)


def pread_into(fd: int, buffer, offset: int) -> int:
    """Read into ``buffer`` (a writable uint8 array or memoryview) from file offset ``offset``
    without an intermediate bytes object where the platform has ``os.preadv``; bytes read."""
    if _PREADV is not None:
        return _PREADV(fd, (buffer,), offset)
    data = os.pread(fd, len(buffer), offset)
    memoryview(buffer)[: len(data)] = data
    return len(data)


_PREADV = getattr(os, "preadv", None)


def _page_header(fd: int, path: str, pos: int, end: int) -> tuple[dict[int, object], bytes]:
    """The PageHeader at file offset ``pos`` and its raw bytes."""
    want = _HEADER_READ
    while True:
        buf = _pread(fd, min(want, end - pos), pos)
        try:
            fields, size = read_struct(buf, 0)
            return fields, buf[:size]
        except IndexError:
            if want >= _MAX_HEADER or pos + len(buf) >= end:
                raise ShardError(f"{path}: image page header at byte {pos} is cut off (truncated or corrupt)") from None
            want *= 4
        except ThriftError as exc:
            raise ShardError(f"{path}: image page header at byte {pos} is corrupt: {exc}") from None


def image_column_index(metadata: pq.FileMetaData) -> int:
    """The leaf column index of ``image`` in a frames file's Parquet schema."""
    for i in range(metadata.num_columns):
        if metadata.schema.column(i).path == "image":
            return i
    raise ValueError("no image column")


def _hash_range(fd: int, hasher, start: int, end: int, keep=None, path: str = "") -> None:
    """Feed bytes ``[start, end)`` to ``hasher`` (if any), read into ``keep[start:end]`` (if given)."""
    if keep is not None:
        if start < end:
            view = memoryview(keep)[start:end]
            got = pread_into(fd, view, start)
            if got != end - start:
                raise ShardError(f"{path}: cut off at byte {start + got} (truncated)")
            if hasher is not None:
                hasher.update(view)
        return
    while start < end:
        block = _pread(fd, min(_BLOCK, end - start), start)
        if not block:
            return
        hasher.update(block)
        start += len(block)


def check_page_crc(path: str, pos: int, crc: object, body: bytes) -> None:
    """ShardError unless ``body`` (of the page at ``pos``) matches its header's CRC32."""
    if not isinstance(crc, int):
        raise ShardError(f"{path}: image page at byte {pos} has no checksum")
    if zlib.crc32(body) != crc & 0xFFFFFFFF:
        raise ShardError(f"{path}: image page at byte {pos} fails its CRC32 checksum (corrupt or tampered)")


def page_values(path: str, pos: int, body: bytes, start: int, count: int) -> tuple[list[int], list[int]]:
    """File offsets and lengths of the ``count`` PLAIN values in a page body that starts at ``start``."""
    offsets, lengths = [], []
    q = 0
    try:
        for _ in range(count):
            (length,) = _LENGTH.unpack_from(body, q)
            q += 4
            offsets.append(start + q)
            lengths.append(length)
            q += length
    except struct.error:
        q = len(body) + 1
    if q != len(body):
        raise ShardError(f"{path}: image page at byte {pos} does not hold {count} whole values (corrupt)")
    return offsets, lengths


@dataclass(frozen=True)
class ImagePage:
    """One data page of the image column: its first row, header position, body and CRC."""

    first_row: int
    pos: int
    body_start: int
    body_size: int
    count: int
    crc: object


def image_pages(source, path: str, metadata: pq.FileMetaData) -> list[ImagePage]:
    """The image column's data pages, found by reading only their headers (one small ranged
    read each): how a remote frames file is indexed without downloading it."""
    column = image_column_index(metadata)
    pages: list[ImagePage] = []
    row = 0
    for group in range(metadata.num_row_groups):
        chunk = metadata.row_group(group).column(column)
        rows = metadata.row_group(group).num_rows
        pos, end = chunk.data_page_offset, chunk.data_page_offset + chunk.total_compressed_size
        seen = 0
        while pos < end:
            header, raw = _page_header(source, path, pos, end)
            kind, body_size, page = header.get(1), header.get(3), header.get(5)
            if kind != DATA_PAGE or not isinstance(page, dict) or page.get(2) != PLAIN:
                raise ShardError(f"{path}: image page at byte {pos} is not a PLAIN data page v1")
            count, start = page.get(1), pos + len(raw)
            if not isinstance(body_size, int) or body_size < 0 or start + body_size > end:
                raise ShardError(f"{path}: image page at byte {pos} runs past its column chunk (corrupt)")
            if not isinstance(count, int) or count < 0 or seen + count > rows:
                raise ShardError(f"{path}: image page at byte {pos} claims {count!r} values, more than the row group")
            pages.append(ImagePage(row + seen, pos, start, body_size, count, header.get(4)))
            seen += count
            pos = start + body_size
        if seen != rows:
            raise ShardError(f"{path}: image pages of row group {group} hold {seen} values, expected {rows}")
        row += rows
    return pages


def image_offsets(
    fd: int,
    path: str,
    metadata: pq.FileMetaData,
    check_crc: bool = True,
    hasher=None,
    size: int | None = None,
    keep=None,
) -> tuple[list[int], list[int]]:
    """File offsets and lengths (one per row, in file order) of the image values.

    ``fd`` is an open descriptor of ``path``; ``metadata`` its parsed footer. With a
    ``hashlib`` ``hasher`` and the file's ``size``, every byte of the file is also fed
    to it, in order, in the same pass (the image bytes are read once). ``keep``, a
    writable uint8 buffer of the file's size, receives every byte outside the image
    column (footer and other columns: what a Parquet reader then reads from memory).
    """
    if keep is not None:
        size = len(keep)
    try:
        column = image_column_index(metadata)
    except ValueError:
        raise ShardError(f"{path}: no image column") from None
    leaf = metadata.schema.column(column)
    if leaf.physical_type != "BYTE_ARRAY" or leaf.max_definition_level or leaf.max_repetition_level:
        raise ShardError(f"{path}: image column is not a required BYTE_ARRAY (written by another writer?)")
    offsets: list[int] = []
    lengths: list[int] = []
    hashed = 0  # bytes of the file fed to the hasher so far
    for group in range(metadata.num_row_groups):
        chunk = metadata.row_group(group).column(column)
        rows = metadata.row_group(group).num_rows
        if chunk.compression != "UNCOMPRESSED" or chunk.dictionary_page_offset is not None:
            raise ShardError(
                f"{path}: image column of row group {group} is {chunk.compression} "
                f"{'with' if chunk.dictionary_page_offset is not None else 'without'} a dictionary; "
                "expected uncompressed PLAIN values"
            )
        pos = chunk.data_page_offset
        end = pos + chunk.total_compressed_size
        if hasher is not None or keep is not None:
            if pos < hashed:
                raise ShardError(f"{path}: image column chunks overlap or are out of order (corrupt)")
            _hash_range(fd, hasher, hashed, pos, keep, path)
        seen = 0
        while pos < end:
            header, raw = _page_header(fd, path, pos, end)
            kind, body_size, page = header.get(1), header.get(3), header.get(5)
            if kind != DATA_PAGE or not isinstance(page, dict) or page.get(2) != PLAIN:
                raise ShardError(f"{path}: image page at byte {pos} is not a PLAIN data page v1")
            count = page.get(1)
            start = pos + len(raw)
            if not isinstance(body_size, int) or body_size < 0 or start + body_size > end:
                raise ShardError(f"{path}: image page at byte {pos} runs past its column chunk (corrupt)")
            if not isinstance(count, int) or count < 0 or seen + count > rows:
                raise ShardError(f"{path}: image page at byte {pos} claims {count!r} values, more than the row group")
            body = _pread(fd, body_size, start)
            if len(body) != body_size:
                raise ShardError(f"{path}: image page at byte {pos} is cut off (truncated)")
            if hasher is not None:
                hasher.update(raw)
                hasher.update(body)
            if check_crc:
                check_page_crc(path, pos, header.get(4), body)
            page_offsets, page_lengths = page_values(path, pos, body, start, count)
            offsets.extend(page_offsets)
            lengths.extend(page_lengths)
            seen += count
            pos = start + body_size
        if seen != rows:
            raise ShardError(f"{path}: row group {group} has {seen} images for {rows} rows (corrupt)")
        hashed = end
    if len(offsets) != metadata.num_rows:
        raise ShardError(f"{path}: {len(offsets)} images for {metadata.num_rows} rows (corrupt)")
    if hasher is not None or keep is not None:
        if size is None:
            raise ValueError("hashing needs the file size")
        _hash_range(fd, hasher, hashed, size, keep, path)
    return offsets, lengths
