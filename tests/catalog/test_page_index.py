"""The frames files' page index: the image pages it lists are the ones the page walk finds,
and a reader fetching one page per image (the remote path) gets every JPEG byte for byte."""

from __future__ import annotations

import os

import pyarrow.parquet as pq
import pytest

from catalog.store.manifest import load_manifest
from catalog.tables.page_index import image_page_locations
from catalog.tables.pages import image_column_index, image_offsets, image_pages
from catalog.tables.remote_images import RemoteImages
from schemas.errors import ShardError


class LocalRanges:
    """The remote reader's contract (``pread(length, offset)``) over a local file, counting bytes."""

    def __init__(self, path):
        self.fd = os.open(path, os.O_RDONLY)
        self.fetched = 0

    def pread(self, length, offset):
        self.fetched += length
        return os.pread(self.fd, length, offset)


def _frames_files(slice_dir):
    return [slice_dir / s.files["frames"].path for s in load_manifest(slice_dir).shards]


def test_the_offset_index_lists_the_pages_the_walk_finds(slice_dir):
    for path in _frames_files(slice_dir):
        metadata = pq.ParquetFile(path).metadata
        reader = LocalRanges(path)
        listed = image_page_locations(reader.pread, str(path), path.stat().st_size, image_column_index(metadata))
        walked = image_pages(reader.fd, str(path), metadata)
        assert [(p.first_row, p.offset, p.size) for p in listed] == [
            (w.first_row, w.pos, w.body_start - w.pos + w.body_size) for w in walked
        ]
        assert len(listed) > 1  # small pages: an image costs a page, not a row group


def test_one_page_per_image_gives_every_jpeg(slice_dir):
    for path in _frames_files(slice_dir):
        metadata = pq.ParquetFile(path).metadata
        reader = LocalRanges(path)
        pages = image_page_locations(reader.pread, str(path), path.stat().st_size, image_column_index(metadata))
        images = RemoteImages(reader, str(path), pages)
        offsets, lengths = image_offsets(reader.fd, str(path), metadata)
        before = reader.fetched
        for row in range(metadata.num_rows):
            assert images.jpeg(row) == os.pread(reader.fd, lengths[row], offsets[row])
        pages_bytes = sum(p.size for p in pages)
        assert reader.fetched - before == pages_bytes  # each page fetched once, in order
        assert pages_bytes < path.stat().st_size


def test_a_corrupt_page_is_named(slice_dir):
    path = _frames_files(slice_dir)[0]
    metadata = pq.ParquetFile(path).metadata
    reader = LocalRanges(path)
    pages = image_page_locations(reader.pread, str(path), path.stat().st_size, image_column_index(metadata))
    data = bytearray(path.read_bytes())
    data[pages[0].offset + pages[0].size - 3] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(ShardError, match=r"image page at byte \d+ fails its CRC32"):
        RemoteImages(LocalRanges(path), str(path), pages).jpeg(0)
