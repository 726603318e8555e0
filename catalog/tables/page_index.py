"""The image column's page locations from a Parquet file's offset index (the page index
Dyana writes since dataset 3.0.0): where each data page starts, its size with its header,
and its first row, read from the footer alone, so a remote reader needs no pass over the
file to find the page holding a row's image.

The footer (``FileMetaData``) and the ``OffsetIndex`` are Thrift compact structs, parsed
with :mod:`catalog.tables.pages`'s reader: ``FileMetaData.row_groups`` (field 4) ->
``RowGroup.columns`` (1) -> ``ColumnChunk.offset_index_offset`` (4) and ``_length`` (5);
``OffsetIndex.page_locations`` (1) -> ``PageLocation`` {offset (1), compressed_page_size
(2), first_row_index (3)}.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

from catalog.tables.thrift import ThriftError, read_struct
from schemas.errors import ShardError

_FOOTER_TAIL = 8


@dataclass(frozen=True)
class PageLocation:
    """One data page of the image column: its first row (in the file), file offset of its
    header and size including the header."""

    first_row: int
    offset: int
    size: int


def _parse(path: str, data: bytes, what: str) -> dict:
    try:
        fields, _ = read_struct(data, 0)
    except (IndexError, ThriftError) as exc:
        raise ShardError(f"{path}: corrupt Parquet {what} ({type(exc).__name__})") from None
    return fields


def image_page_locations(read: Callable[[int, int], bytes], path: str, size: int,
                         column: int) -> list[PageLocation] | None:
    """The leaf ``column``'s data pages, in file order, from the offset index; None when the
    file has none (written before dataset 3.0.0). ``read(length, offset)`` reads bytes."""
    tail = read(_FOOTER_TAIL, size - _FOOTER_TAIL)
    if len(tail) != _FOOTER_TAIL or tail[4:] != b"PAR1":
        raise ShardError(f"{path}: not a Parquet file (no PAR1 footer)")
    (length,) = struct.unpack("<I", tail[:4])
    if length > size - 2 * _FOOTER_TAIL:
        raise ShardError(f"{path}: Parquet footer length {length} exceeds the file")
    footer = _parse(path, read(length, size - _FOOTER_TAIL - length), "footer")
    pages: list[PageLocation] = []
    row = 0
    for group in footer.get(4, []):
        chunk = group.get(1, [])[column] if isinstance(group, dict) and column < len(group.get(1, [])) else None
        offset, index_length = (chunk.get(4), chunk.get(5)) if isinstance(chunk, dict) else (None, None)
        if not isinstance(offset, int) or not isinstance(index_length, int):
            return None
        index = _parse(path, read(index_length, offset), "offset index")
        for location in index.get(1, []):
            first, start, bytes_ = location.get(3), location.get(1), location.get(2)
            if not all(isinstance(v, int) and v >= 0 for v in (first, start, bytes_)):
                raise ShardError(f"{path}: corrupt Parquet offset index at byte {offset}")
            pages.append(PageLocation(row + first, start, bytes_))
        row += group.get(3, 0)
    return pages
