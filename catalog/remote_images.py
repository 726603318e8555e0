"""A remote frames file's JPEGs, read with ranged requests: the image pages are located
from their headers when the shard is opened, and an item fetches the one data page that
holds its image (checked against the page's CRC32), kept in a small per-shard LRU so that
neighbouring frames cost no second request. Nothing is downloaded whole."""

from __future__ import annotations

import bisect
import threading
from collections import OrderedDict

from catalog.pages import ImagePage, check_page_crc, page_values
from catalog.storage import RangeReader

#: Decoded pages kept per open remote shard.
PAGES_KEPT = 8


class RemoteImages:
    """The image column of one remote frames file."""

    fd = None  # not a descriptor: :class:`catalog.shard_cache.OpenShard` asks :meth:`jpeg`

    def __init__(self, reader: RangeReader, path: str, pages: list[ImagePage]) -> None:
        self.reader, self.path, self.pages = reader, path, pages
        self._firsts = [page.first_row for page in pages]
        self._kept: OrderedDict[int, tuple[bytes, list[int], list[int]]] = OrderedDict()
        self._lock = threading.Lock()

    def jpeg(self, row: int) -> bytes:
        index = bisect.bisect_right(self._firsts, row) - 1
        page = self.pages[index]
        with self._lock:
            kept = self._kept.get(index)
            if kept is not None:
                self._kept.move_to_end(index)
        if kept is None:
            body = self.reader.pread(page.body_size, page.body_start)
            check_page_crc(self.path, page.pos, page.crc, body)
            offsets, lengths = page_values(self.path, page.pos, body, page.body_start, page.count)
            kept = (body, offsets, lengths)
            with self._lock:
                self._kept[index] = kept
                while len(self._kept) > PAGES_KEPT:
                    self._kept.popitem(last=False)
        body, offsets, lengths = kept
        k = row - page.first_row
        start = offsets[k] - page.body_start
        return body[start:start + lengths[k]]
