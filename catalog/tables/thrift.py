"""Thrift's compact protocol, decoded just far enough to read Parquet page headers.

Parquet stores each page's header (and the page index) as a Thrift struct in the compact
protocol; pyarrow does not expose them, so :mod:`catalog.tables.pages`, :mod:`catalog.tables.page_index`
and :mod:`catalog.tables.remote_images` read them with :func:`read_struct`: a struct becomes
``{field id: value}`` (lists, maps and nested structs likewise), nothing is named.
"""

from __future__ import annotations


class ThriftError(ValueError):
    """Bytes that are not a Thrift compact-protocol value."""


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    shift = result = 0
    while True:
        byte = buf[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise ThriftError("varint too long")


def _zigzag(n: int) -> int:
    return (n >> 1) ^ -(n & 1)


def _value(buf: bytes, pos: int, kind: int):
    """One Thrift compact-protocol value of type ``kind`` at ``pos``; (value, next pos)."""
    if kind in (1, 2):
        return kind == 1, pos
    if kind == 3:
        return buf[pos], pos + 1
    if kind in (4, 5, 6):
        raw, pos = _varint(buf, pos)
        return _zigzag(raw), pos
    if kind == 7:
        return buf[pos : pos + 8], pos + 8
    if kind == 8:
        size, pos = _varint(buf, pos)
        if pos + size > len(buf):
            raise IndexError("binary past the buffer")
        return buf[pos : pos + size], pos + size
    if kind in (9, 10):
        head = buf[pos]
        pos += 1
        size, element = head >> 4, head & 0x0F
        if size == 15:
            size, pos = _varint(buf, pos)
        items = []
        for _ in range(size):
            if element in (1, 2):
                items.append(buf[pos] == 1)
                pos += 1
            else:
                item, pos = _value(buf, pos, element)
                items.append(item)
        return items, pos
    if kind == 11:
        size, pos = _varint(buf, pos)
        if size == 0:
            return {}, pos
        types = buf[pos]
        pos += 1
        mapping = {}
        for _ in range(size):
            key, pos = _value(buf, pos, types >> 4)
            mapping[key], pos = _value(buf, pos, types & 0x0F)
        return mapping, pos
    if kind == 12:
        return read_struct(buf, pos)
    raise ThriftError(f"unknown Thrift type {kind}")


def read_struct(buf: bytes, pos: int) -> tuple[dict[int, object], int]:
    """A Thrift compact struct as {field id: value}."""
    fields: dict[int, object] = {}
    last = 0
    while True:
        head = buf[pos]
        pos += 1
        if head == 0:
            return fields, pos
        kind, delta = head & 0x0F, head >> 4
        if delta:
            field_id = last + delta
        else:
            raw, pos = _varint(buf, pos)
            field_id = _zigzag(raw)
        last = field_id
        fields[field_id], pos = _value(buf, pos, kind)
