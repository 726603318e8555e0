"""The per-frame MCAP messages of a shard as protobuf bytes, encoded directly: the same
bytes as building each message with the protobuf runtime and calling
``SerializeToString(deterministic=True)``, several times faster (that runtime costs
about a microsecond per field set from Python, and a frame sets ~600).

What makes that exact: a deterministic serialisation writes a message's fields in
field-number order, each as its tag then its value, so a message is the concatenation
of its fields' encodings and any run of fields that never changes can be serialised
once by the runtime (:func:`fields`) and reused. The varying fields are encoded here
under proto3's rules as that runtime applies them: a ``double`` is written unless its
bits are all zero (``0.0`` is left out, ``-0.0`` is written), a ``uint32``/``int64``
unless zero, and a sub-message whenever it was set, even if empty (every sub-message
below is set on every frame). ``tests/catalog/test_mcap_encode.py`` compares every
encoder with the runtime's bytes, zeros and negative zeros included.

The episode's numbers are packed by numpy in one pass (:func:`rows`); only a row
holding a zero is encoded value by value.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence

import numpy as np
from google.protobuf.message import Message

#: Wire types: 64-bit (a double), length-delimited.
_I64, _LEN = 1, 2
_ZERO = b"\x00" * 8
_SMALL = [bytes((v,)) for v in range(0x80)]
#: Length-delimited tags of fields 1..15 (one byte each).
_LEN_TAGS = [b""] + [bytes((field << 3 | _LEN,)) for field in range(1, 16)]


def varint(value: int) -> bytes:
    """A non-negative integer as a protobuf varint."""
    if value < 0x80:
        return _SMALL[value]
    out = bytearray()
    while value >= 0x80:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def length_delimited(field: int, payload: bytes) -> bytes:
    """Field ``field`` (1..15) holding a string, bytes or a sub-message's encoding."""
    size = len(payload)
    return _LEN_TAGS[field] + (_SMALL[size] if size < 0x80 else varint(size)) + payload


def fields(message: Message) -> bytes:
    """The set fields of ``message`` as the runtime serialises them (for the runs of
    fields that never change)."""
    return message.SerializeToString(deterministic=True)


def timestamp(ns: int) -> bytes:
    """A ``google.protobuf.Timestamp`` of ``ns`` nanoseconds (>= 0): seconds (field 1),
    nanos (field 2), each left out when zero."""
    seconds, nanos = divmod(ns, 10**9)
    out = b""
    if seconds:
        out += b"\x08" + varint(seconds)
    if nanos:
        out += b"\x10" + varint(nanos)
    return out


def doubles(values: Sequence[float]) -> bytes:
    """A message whose fields 1..k are the doubles ``values`` (``foxglove.Vector3``,
    ``Point3``, ``Quaternion``): each left out when its bits are all zero."""
    out = []
    for k, value in enumerate(values):
        packed = struct.pack("<d", value)
        if packed != _ZERO:
            out.append(bytes((k + 1 << 3 | _I64,)) + packed)
    return b"".join(out)


def rows(values: np.ndarray, encode_row: Callable[[Sequence[float]], bytes]) -> list[bytes]:
    """``encode_row`` of every row of ``values`` (m, k), float64, which must place each
    value of a row once as an 8-byte double, or leave it out when its bits are zero:
    the same bytes, packed by numpy. Rows whose zeros sit in the same columns share one
    layout; it is taken from ``encode_row`` of a row of distinct sentinel values (zeros
    in those columns), and the rows' doubles are written into copies of it."""
    values = np.ascontiguousarray(values, dtype=np.float64)
    m, k = values.shape
    zero = values.view(np.uint64) == 0
    codes = zero @ (1 << np.arange(k, dtype=np.int64))
    sentinel = 1.0 + np.arange(1, k + 1) * 2.0**-30
    encoded: list[bytes] = [b""] * m
    for code in np.unique(codes).tolist():
        which = np.flatnonzero(codes == code)
        kept = np.flatnonzero(~zero[which[0]]).tolist()
        layout = encode_row(np.where(zero[which[0]], 0.0, sentinel).tolist())
        block = np.repeat(np.frombuffer(layout, dtype=np.uint8)[None], len(which), axis=0)
        for j in kept:
            packed = struct.pack("<d", sentinel[j])
            if layout.count(packed) != 1:
                raise ValueError("encode_row must place each value of a row exactly once")
            offset = layout.index(packed)
            block[:, offset : offset + 8] = np.ascontiguousarray(values[which, j]).view(np.uint8).reshape(-1, 8)
        raw, width = block.tobytes(), len(layout)
        for r, i in enumerate(which.tolist()):
            encoded[i] = raw[r * width : (r + 1) * width]
    return encoded
