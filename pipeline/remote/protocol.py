"""The remote-policy wire protocol ``dyana/1``: msgpack messages over WebSocket.

Every message is one binary WebSocket frame holding a msgpack map with a ``type``.
Numpy arrays travel as typed buffers, a map
``{"__ndarray__": true, "dtype": "<f4", "shape": [H, 18], "data": <bin>}`` with the
raw little-endian, C-order bytes; nothing is ever pickled, and msgpack extension
types are refused. Messages (docs/reference/wire-protocol.md):

- server -> client on connect: ``metadata`` {protocol, policy, action_horizon, privileged}
- client -> server ``reset`` {task} -> server ``ready``
- client -> server ``act`` {observation} -> server ``action`` {action, server_time_ms}
- either way ``error`` {message}

:func:`decode` and :func:`parse` check what arrives and raise :class:`ProtocolError`
(a :class:`~schemas.errors.PolicyError`) with a message naming the bad part.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import msgpack
import numpy as np

from pipeline.loop.actions import float32_copy
from pipeline.remote.limits import LimitError, check_shape, scan
from schemas.errors import PolicyError
from schemas.names import redact_credentials

PROTOCOL = "dyana/1"
ARRAY_KEY = "__ndarray__"
#: Largest request a server accepts by default: an act message with a 94-frame observe
#: window up to 448 px (~57 MB) fits; beyond, raise it (``pipeline serve --max-message-mb``).
MAX_MESSAGE_BYTES = 64 << 20
#: Largest reply a client accepts: metadata, ready, an (H, 18) action or an error.
MAX_REPLY_BYTES = 1 << 20
#: Connections a server handles at once by default; more are refused (busy).
MAX_CONNECTIONS = 4
MAX_NDIM = 8

#: dtype strings accepted on the wire -> numpy dtype (little-endian or byte-order-free).
_DTYPES = {
    "|b1": np.dtype(np.bool_),
    "|u1": np.dtype(np.uint8),
    "|i1": np.dtype(np.int8),
    "<u2": np.dtype("<u2"),
    "<i2": np.dtype("<i2"),
    "<u4": np.dtype("<u4"),
    "<i4": np.dtype("<i4"),
    "<u8": np.dtype("<u8"),
    "<i8": np.dtype("<i8"),
    "<f2": np.dtype("<f2"),
    "<f4": np.dtype("<f4"),
    "<f8": np.dtype("<f8"),
}
for _name in ("b1", "u1", "i1"):
    _DTYPES["<" + _name] = _DTYPES["|" + _name]

#: Message type -> required fields and their Python types (after decoding).
MESSAGES: dict[str, dict[str, tuple[type, ...]]] = {
    "metadata": {"protocol": (str,), "policy": (str,), "action_horizon": (int,), "privileged": (bool,)},
    "reset": {"task": (dict,)},
    "ready": {},
    "act": {"observation": (dict,)},
    "action": {"action": (np.ndarray,), "server_time_ms": (int, float)},
    "error": {"message": (str,)},
}


class ProtocolError(PolicyError):
    """A message that is not valid ``dyana/1``: undecodable, of an unknown type, or
    with a missing or mistyped field."""


def _wire_dtype(dtype: np.dtype) -> str:
    little = dtype.newbyteorder("<") if dtype.byteorder == ">" else dtype
    text = little.str
    if text not in _DTYPES:
        raise ProtocolError(f"arrays of dtype {dtype} cannot be sent (allowed: {sorted(set(_DTYPES))})")
    return text


def _pack_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        text = _wire_dtype(value.dtype)
        if value.ndim > MAX_NDIM:
            raise ProtocolError(f"arrays of more than {MAX_NDIM} dimensions cannot be sent, got shape {value.shape}")
        data = np.ascontiguousarray(value, dtype=_DTYPES[text]).tobytes()
        return {ARRAY_KEY: True, "dtype": text, "shape": list(value.shape), "data": data}
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    raise ProtocolError(f"a value of type {type(value).__name__} cannot be sent (only msgpack types and numpy arrays)")


def encode(message: Mapping[str, Any]) -> bytes:
    """A message (a dict with ``type``) as msgpack bytes; arrays become typed buffers."""
    if not isinstance(message, Mapping) or message.get("type") not in MESSAGES:
        raise ProtocolError(f"a message must be a dict whose type is one of {sorted(MESSAGES)}, got {message!r:.200}")
    try:
        return msgpack.packb(dict(message), default=_pack_default, use_bin_type=True, strict_types=False)
    except ProtocolError:
        raise
    except (TypeError, ValueError, OverflowError) as exc:
        raise ProtocolError(f"cannot encode {message.get('type')} message: {exc}") from None


def _array(obj: dict[str, Any]) -> np.ndarray:
    if obj.get(ARRAY_KEY) is not True or set(obj) != {ARRAY_KEY, "dtype", "shape", "data"}:
        raise ProtocolError(f"an array must be exactly {{{ARRAY_KEY}: true, dtype, shape, data}}, got keys {sorted(obj)}")
    text, shape, data = obj["dtype"], obj["shape"], obj["data"]
    if not isinstance(text, str) or text not in _DTYPES:
        raise ProtocolError(f"array dtype {text!r} is not accepted (allowed: {sorted(_DTYPES)})")
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
    dtype = _DTYPES[text]
    expected = math.prod(shape) * dtype.itemsize
    if len(data) != expected:
        raise ProtocolError(f"array of dtype {text} and shape {shape} needs {expected} bytes, got {len(data)}")
    return np.frombuffer(data, dtype=dtype).reshape(shape).astype(dtype.newbyteorder("="), copy=True)


def _object_hook(obj: dict[Any, Any]) -> Any:
    bad = [k for k in obj if not isinstance(k, str)]
    if bad:
        raise ProtocolError(f"map keys must be strings, got {bad[0]!r}")
    if ARRAY_KEY in obj:
        return _array(obj)
    return obj


def _ext_hook(code: int, data: bytes) -> Any:
    raise ProtocolError(f"msgpack extension type {code} is not part of {PROTOCOL} (arrays are typed-buffer maps)")


def _refuse_extensions(value: Any) -> None:
    """msgpack decodes its timestamp extension (-1) itself, past ``ext_hook``: refuse it here."""
    if isinstance(value, msgpack.Timestamp):
        raise ProtocolError(f"msgpack extension type -1 (timestamp) is not part of {PROTOCOL}")
    if isinstance(value, dict):
        for item in value.values():
            _refuse_extensions(item)
    elif isinstance(value, list):
        for item in value:
            _refuse_extensions(item)


def decode(data: bytes | str) -> dict[str, Any]:
    """msgpack bytes -> a message dict with arrays rebuilt (writable, native byte order); a
    text frame is a ProtocolError."""
    if isinstance(data, str):
        raise ProtocolError(f"{PROTOCOL} messages are binary frames of msgpack, got a text frame: {data[:80]!r}")
    try:
        scan(data)  # bounded: nothing is built for a message of millions of values
        message = msgpack.unpackb(
            data,
            raw=False,
            object_hook=_object_hook,
            ext_hook=_ext_hook,
            strict_map_key=False,
        )
    except ProtocolError:
        raise
    except LimitError as exc:
        raise ProtocolError(str(exc)) from None
    except Exception as exc:  # msgpack raises several unrelated exception types
        raise ProtocolError(f"not a msgpack message ({type(exc).__name__}: {exc})") from None
    if not isinstance(message, dict):
        raise ProtocolError(f"a message must be a msgpack map, got {type(message).__name__}")
    _refuse_extensions(message)
    return message


def check(message: dict[str, Any], expected: tuple[str, ...] | None = None) -> dict[str, Any]:
    """Check a decoded message's type and fields; ``expected`` limits the allowed types."""
    kind = message.get("type")
    if kind not in MESSAGES:
        raise ProtocolError(f"unknown message type {kind!r} (known: {sorted(MESSAGES)})")
    if expected is not None and kind not in expected and kind != "error":
        raise ProtocolError(f"expected a {' or '.join(expected)} message, got {kind!r}")
    for name, types in MESSAGES[kind].items():
        if name not in message:
            raise ProtocolError(f"{kind} message is missing {name!r}")
        value = message[name]
        if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
            wanted = " or ".join(t.__name__ for t in types)
            raise ProtocolError(f"{kind} message field {name!r} must be {wanted}, got {type(value).__name__}")
    if kind == "action" and message["action"].dtype.kind not in "fiu":
        raise ProtocolError(f"an action must be a real-valued array, got dtype {message['action'].dtype}")
    if kind == "metadata":
        if message["protocol"] != PROTOCOL:
            raise ProtocolError(f"server speaks protocol {message['protocol']!r}, this client speaks {PROTOCOL!r}")
        if message["action_horizon"] < 1:
            raise ProtocolError(f"metadata action_horizon must be >= 1, got {message['action_horizon']!r}")
    return message


def parse(data: bytes | str, expected: tuple[str, ...] | None = None) -> dict[str, Any]:
    """:func:`decode` then :func:`check`."""
    return check(decode(data), expected)


def metadata_message(name: str, action_horizon: int, privileged: bool) -> dict[str, Any]:
    return {
        "type": "metadata",
        "protocol": PROTOCOL,
        "policy": str(name),
        "action_horizon": int(action_horizon),
        "privileged": bool(privileged),
    }


def reset_message(task: Mapping[str, Any]) -> dict[str, Any]:
    return {"type": "reset", "task": dict(task)}


def act_message(observation: Mapping[str, Any]) -> dict[str, Any]:
    """The observation as sent; ``timestamp`` (a 0-d array in the environment, to match its
    Gymnasium space) travels as a plain float, as the protocol documents."""
    out = dict(observation)
    if "timestamp" in out:
        out["timestamp"] = float(out["timestamp"])
    return {"type": "act", "observation": out}


def action_message(action: Any, server_time_ms: float) -> dict[str, Any]:
    """The action as sent: a float32 ``(H, 18)`` chunk (a policy's float64 output is cast, as
    in-process; a single ``(18,)`` row becomes a chunk of one). What in-process refuses
    (complex values, an unconvertible object) raises the same PolicyError here."""
    array = float32_copy(action)
    if array.ndim == 1:
        array = array[None]
    return {"type": "action", "action": array, "server_time_ms": float(server_time_ms)}


def error_message(message: str) -> dict[str, Any]:
    return {"type": "error", "message": str(message)}


def describe_error(exc: BaseException) -> str:
    """``exc`` as one line for a client's error message: its type and its text with any
    credentials in it redacted (a URL's user:password never reaches a log)."""
    text = redact_credentials(str(exc))
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def close_reason(exc: Exception) -> str:
    """Why a WebSocket connection closed (``websockets``' ConnectionClosed ``exc``): the close
    code and reason, or that the client closed it for a reply over :data:`MAX_REPLY_BYTES`."""
    sent, rcvd = getattr(exc, "sent", None), getattr(exc, "rcvd", None)
    if sent is not None and sent.code == 1009:  # websockets closes when a reply exceeds max_size
        return f"code 1009, a reply over {MAX_REPLY_BYTES >> 20} MiB"
    if rcvd is None:
        return "no close frame received"
    reason = f", {rcvd.reason}" if rcvd.reason else ""
    return f"code {rcvd.code}{reason}"
