"""openpi's wire encoding: msgpack with numpy arrays as maps keyed by *bytes*.

openpi (``openpi_client.msgpack_numpy``) packs an array as the map
``{b"__ndarray__": True, b"data": <bin>, b"dtype": "<f4", b"shape": [H, D]}`` and a numpy
scalar as ``{b"__npgeneric__": True, b"data": <value>, b"dtype": "<f4"}``: the marker keys
are msgpack *bin*, the dtype a str, the data the raw C-order bytes. Every other map of a
message has str keys. That is the one difference from ``dyana/1``'s typed buffers (str keys),
besides the envelope (openpi sends bare dicts, no ``type``). :func:`encode` writes exactly
openpi's form; :func:`decode` reads it with the same checks as ``dyana/1``: allowed dtypes
only, a byte count that matches the shape, no extension types, nothing pickled. Faults raise
:class:`~pipeline.remote.protocol.ProtocolError` naming the bad part.
"""

from __future__ import annotations

import math
import re
from typing import Any

import msgpack
import numpy as np

from pipeline.remote.limits import LimitError, check_shape, scan
from pipeline.remote.protocol import MAX_NDIM, ProtocolError

ARRAY = b"__ndarray__"
SCALAR = b"__npgeneric__"
_ARRAY_KEYS = {ARRAY, b"data", b"dtype", b"shape"}
_SCALAR_KEYS = {SCALAR, b"data", b"dtype"}
#: Array dtypes accepted: any byte order of these kinds and sizes, and str arrays (``<U n``).
_DTYPE = re.compile(r"[<>|](b1|u1|i1|u2|i2|u4|i4|u8|i8|f2|f4|f8|U[1-9][0-9]{0,3})")


def _dtype(text: Any) -> np.dtype:
    if not isinstance(text, str) or not _DTYPE.fullmatch(text):
        raise ProtocolError(f"array dtype {text!r:.40} is not accepted (numeric, bool or str arrays: e.g. '<f4', '|u1')")
    return np.dtype(text)


def _pack_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        text = value.dtype.str
        _dtype(text)
        if value.ndim > MAX_NDIM:
            raise ProtocolError(f"arrays of more than {MAX_NDIM} dimensions cannot be sent, got shape {value.shape}")
        return {ARRAY: True, b"data": np.ascontiguousarray(value).tobytes(), b"dtype": text, b"shape": list(value.shape)}
    if isinstance(value, (np.bool_, np.integer, np.floating, np.str_)):
        return value.item()
    raise ProtocolError(f"a value of type {type(value).__name__} cannot be sent (only msgpack types and numpy arrays)")


def encode(message: dict[str, Any]) -> bytes:
    """A dict as openpi's msgpack bytes (arrays as bytes-keyed maps, numpy scalars as plain values)."""
    if not isinstance(message, dict):
        raise ProtocolError(f"an openpi message is a dict, got {type(message).__name__}")
    try:
        return msgpack.packb(message, default=_pack_default, use_bin_type=True)
    except ProtocolError:
        raise
    except (TypeError, ValueError, OverflowError) as exc:
        raise ProtocolError(f"cannot encode the message: {exc}") from None


def _array(obj: dict[Any, Any]) -> np.ndarray:
    if set(obj) != _ARRAY_KEYS or obj[ARRAY] is not True:
        raise ProtocolError(f"an array is exactly {{b'__ndarray__': true, b'data', b'dtype', b'shape'}}, got keys {sorted(map(repr, obj))}")
    dtype, shape, data = _dtype(obj[b"dtype"]), obj[b"shape"], obj[b"data"]
    if (
        not isinstance(shape, list)
        or len(shape) > MAX_NDIM
        or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)
    ):
        raise ProtocolError(f"array shape must be a list of at most {MAX_NDIM} integers >= 0, got {shape!r:.80}")
    try:
        check_shape(shape)
    except LimitError as exc:
        raise ProtocolError(str(exc)) from None
    if not isinstance(data, bytes):
        raise ProtocolError(f"array data must be msgpack bin, got {type(data).__name__}")
    expected = math.prod(shape) * dtype.itemsize
    if len(data) != expected:
        raise ProtocolError(f"array of dtype {dtype.str} and shape {shape} needs {expected} bytes, got {len(data)}")
    return np.frombuffer(data, dtype=dtype).reshape(shape).astype(dtype.newbyteorder("="), copy=True)


def _scalar(obj: dict[Any, Any]) -> Any:
    if set(obj) != _SCALAR_KEYS or obj[SCALAR] is not True:
        raise ProtocolError(f"a numpy scalar is exactly {{b'__npgeneric__': true, b'data', b'dtype'}}, got keys {sorted(map(repr, obj))}")
    dtype, data = _dtype(obj[b"dtype"]), obj[b"data"]
    if not isinstance(data, (bool, int, float, str)):
        raise ProtocolError(f"a numpy scalar's data must be a number or str, got {type(data).__name__}")
    try:
        return dtype.type(data).item()
    except (TypeError, ValueError, OverflowError) as exc:
        raise ProtocolError(f"numpy scalar {data!r:.40} is not a {dtype.str}: {exc}") from None


def _object_hook(obj: dict[Any, Any]) -> Any:
    if ARRAY in obj:
        return _array(obj)
    if SCALAR in obj:
        return _scalar(obj)
    for key in obj:
        if not isinstance(key, str):
            raise ProtocolError(f"map keys must be strings (bytes keys mark arrays: b'__ndarray__'), got {key!r:.60}")
        if key in ("__ndarray__", "__npgeneric__"):
            raise ProtocolError(f"an array's marker key must be bytes (b'{key}', as openpi's msgpack_numpy writes), got a str")
    return obj


def _ext_hook(code: int, data: bytes) -> Any:
    raise ProtocolError(f"msgpack extension type {code} is not part of openpi's encoding")


def _refuse_timestamps(value: Any) -> None:
    """msgpack decodes its timestamp extension (-1) itself, past ``ext_hook``: refuse it here."""
    if isinstance(value, msgpack.Timestamp):
        raise ProtocolError("msgpack extension type -1 (timestamp) is not part of openpi's encoding")
    if isinstance(value, dict):
        for item in value.values():
            _refuse_timestamps(item)
    elif isinstance(value, list):
        for item in value:
            _refuse_timestamps(item)


def decode(data: bytes | str) -> dict[str, Any]:
    """openpi msgpack bytes -> a dict with arrays rebuilt (writable, native byte order)."""
    if isinstance(data, str):
        raise ProtocolError(f"openpi messages are binary frames of msgpack, got a text frame: {data[:80]!r}")
    try:
        scan(data)  # bounded: nothing is built for a message of millions of values
        message = msgpack.unpackb(data, raw=False, object_hook=_object_hook, ext_hook=_ext_hook, strict_map_key=False)
    except ProtocolError:
        raise
    except LimitError as exc:
        raise ProtocolError(str(exc)) from None
    except Exception as exc:  # msgpack raises several unrelated exception types
        raise ProtocolError(f"not a msgpack message ({type(exc).__name__}: {exc})") from None
    if not isinstance(message, dict):
        raise ProtocolError(f"an openpi message must be a msgpack map, got {type(message).__name__}")
    _refuse_timestamps(message)
    return message


def error_line(text: str, limit: int = 300) -> str:
    """The last non-blank line of an openpi error frame (a traceback ends with the exception), cut short."""
    lines = [line.strip() for line in str(text).splitlines() if line.strip()]
    last = lines[-1] if lines else "(empty error frame)"
    return last if len(last) <= limit else last[: limit - 3] + "..."
