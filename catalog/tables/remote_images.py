"""A remote frames file's JPEGs, read with ranged requests: the image column's data pages
are located from the footer's offset index (:mod:`catalog.tables.page_index`; files without one
are walked header by header), and an item fetches the one page that holds its image (about
32 kB: a handful of JPEGs), checked against the page's CRC32 and kept in a small per-shard
LRU so that neighbouring frames cost no second request. Nothing is downloaded whole."""

from __future__ import annotations

import bisect
import threading
from collections import OrderedDict

import pyarrow.parquet as pq

from catalog.store.storage import RangeReader
from catalog.tables.page_index import PageLocation, image_page_locations
from catalog.tables.pages import (
    DATA_PAGE,
    PLAIN,
    check_page_crc,
    image_column_index,
    image_pages,
    page_values,
)
from catalog.tables.thrift import ThriftError, read_struct
from schemas.errors import ShardError

#: Pages kept per open remote shard.
PAGES_KEPT = 16


class RemoteImages:
    """The image column of one remote frames file."""

    fd = None  # not a descriptor: :class:`catalog.loader.shard_cache.OpenShard` asks :meth:`jpeg`

    def __init__(self, reader: RangeReader, path: str, pages: list[PageLocation]) -> None:
        self.reader, self.path, self.pages = reader, path, pages
        self._firsts = [page.first_row for page in pages]
        self._kept: OrderedDict[int, tuple[bytes, list[int], list[int], int]] = OrderedDict()
        self._lock = threading.Lock()

    def _fetch(self, index: int) -> tuple[bytes, list[int], list[int], int]:
        page = self.pages[index]
        data = self.reader.pread(page.size, page.offset)
        try:
            header, start = read_struct(data, 0)
        except (IndexError, ThriftError):
            raise ShardError(f"{self.path}: image page at byte {page.offset} has a corrupt header") from None
        kind, body_size, values = header.get(1), header.get(3), header.get(5)
        if kind != DATA_PAGE or not isinstance(values, dict) or values.get(2) != PLAIN:
            raise ShardError(f"{self.path}: image page at byte {page.offset} is not a PLAIN data page v1")
        count = values.get(1)
        if not isinstance(body_size, int) or not isinstance(count, int) or start + body_size != len(data):
            raise ShardError(f"{self.path}: image page at byte {page.offset} does not match its offset index")
        body = data[start:]
        check_page_crc(self.path, page.offset, header.get(4), body)
        offsets, lengths = page_values(self.path, page.offset, body, 0, count)
        return body, offsets, lengths, page.first_row

    def jpeg(self, row: int) -> bytes:
        index = bisect.bisect_right(self._firsts, row) - 1
        if index < 0:
            raise ShardError(f"{self.path}: no image page holds row {row}")
        with self._lock:
            kept = self._kept.get(index)
            if kept is not None:
                self._kept.move_to_end(index)
        if kept is None:
            kept = self._fetch(index)
            with self._lock:
                self._kept[index] = kept
                while len(self._kept) > PAGES_KEPT:
                    self._kept.popitem(last=False)
        body, offsets, lengths, first = kept
        k = row - first
        if not 0 <= k < len(offsets):
            raise ShardError(f"{self.path}: image page of row {first} does not hold row {row} (corrupt offset index)")
        return body[offsets[k]:offsets[k] + lengths[k]]


def remote_images(path, where: str, metadata: pq.FileMetaData, size: int) -> RemoteImages:
    """The images of the remote frames file ``path`` (``where`` names it in errors): pages from
    the offset index, or (files without one) from walking the page headers."""
    reader = RangeReader(path)
    pages = image_page_locations(reader.pread, where, size, image_column_index(metadata))
    if pages is None:
        pages = [PageLocation(p.first_row, p.pos, p.body_start - p.pos + p.body_size)
                 for p in image_pages(reader, where, metadata)]
    return RemoteImages(reader, where, pages)
