"""The dyana/1 codec: typed-buffer arrays round-trip exactly; pickle, extension types
and malformed messages are refused with a message naming the problem."""

from __future__ import annotations

import pickle

import msgpack
import numpy as np
import pytest

from pipeline.remote import protocol
from pipeline.remote.protocol import ProtocolError
from schemas.errors import PolicyError

#: Every dtype and shape the closed loop sends, plus the other accepted dtypes.
ARRAYS = {
    "image": np.arange(64 * 48 * 3, dtype=np.uint8).reshape(64, 48, 3),
    "observe_images": np.arange(3 * 8 * 8 * 3, dtype=np.uint8).reshape(3, 8, 8, 3),
    "no_observe_images": np.zeros((0, 8, 8, 3), dtype=np.uint8),
    "palm_pose": np.linspace(-1, 1, 6, dtype=np.float32),
    "joint_angles": np.linspace(0, 1.5, 15, dtype=np.float32),
    "joint_poses": np.linspace(-3, 3, 90, dtype=np.float32),
    "keypoints": np.linspace(-2, 2, 36, dtype=np.float32),
    "action_row": np.linspace(-1, 1, 18, dtype=np.float32),
    "action_chunk": np.linspace(-1, 1, 8 * 18, dtype=np.float32).reshape(8, 18),
    "float64": np.array([np.pi, -0.0, 1e300], dtype=np.float64),
    "float16": np.array([1.5, -2.0], dtype=np.float16),
    "int64": np.array([-(2**62), 2**62], dtype=np.int64),
    "int32": np.array([[1, -2], [3, -4]], dtype=np.int32),
    "int16": np.array([-7], dtype=np.int16),
    "int8": np.array([-128, 127], dtype=np.int8),
    "uint16": np.array([65535], dtype=np.uint16),
    "uint32": np.array([2**32 - 1], dtype=np.uint32),
    "uint64": np.array([2**64 - 1], dtype=np.uint64),
    "bool": np.array([True, False, True]),
    "scalar": np.array(2.5, dtype=np.float32),
    "big_endian": np.array([1.25, -3.5], dtype=">f4"),
    "fortran": np.asfortranarray(np.arange(6, dtype=np.float32).reshape(2, 3)),
    "strided": np.arange(20, dtype=np.float32)[::3],
}


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype.newbyteorder("=") == b.dtype and a.astype(b.dtype).tobytes() == b.tobytes()


def test_arrays_round_trip_bit_exactly():
    observation = dict(ARRAYS, text="pick up the red ball", frame_index=7, timestamp=0.35, nested={"list": [1, 2.0, "x"]})
    decoded = protocol.parse(protocol.encode(protocol.act_message(observation)), ("act",))
    back = decoded["observation"]
    for name, array in ARRAYS.items():
        assert isinstance(back[name], np.ndarray), name
        assert _same(array, back[name]), name
        assert back[name].flags.writeable and back[name].flags.c_contiguous, name
    assert back["text"] == "pick up the red ball"
    assert back["frame_index"] == 7 and isinstance(back["frame_index"], int)
    assert back["timestamp"] == 0.35
    assert back["nested"] == {"list": [1, 2.0, "x"]}


def test_numpy_scalars_become_plain_numbers():
    message = protocol.decode(protocol.encode(protocol.reset_message({"i": np.int64(3), "f": np.float32(0.5), "b": np.bool_(True)})))
    assert message["task"] == {"i": 3, "f": 0.5, "b": True}


def test_every_message_type_round_trips_and_checks():
    messages = [
        protocol.metadata_message("predictive", 1, False),
        protocol.reset_message({"text": "t", "fps": 20, "observe_frames": 0, "horizon": 24, "resolution": 64, "hand": "left"}),
        {"type": "ready"},
        protocol.act_message({"image": ARRAYS["image"]}),
        protocol.action_message(ARRAYS["action_chunk"], 1.5),
        protocol.error_message("boom"),
    ]
    for message in messages:
        back = protocol.parse(protocol.encode(message))
        assert back["type"] == message["type"]


def test_action_message_is_float32_chunk():
    back = protocol.parse(protocol.encode(protocol.action_message(np.ones(18, dtype=np.float64) / 3, 0.1)))
    assert back["action"].dtype == np.float32 and back["action"].shape == (1, 18)  # (H, 18), as documented
    assert back["action"].tobytes() == (np.ones(18, dtype=np.float64) / 3).astype(np.float32).tobytes()


def test_wire_format_is_the_documented_map():
    raw = msgpack.unpackb(protocol.encode(protocol.action_message(np.zeros((2, 18), np.float32), 0.25)), raw=False)
    assert raw["type"] == "action" and raw["server_time_ms"] == 0.25
    assert raw["action"] == {"__ndarray__": True, "dtype": "<f4", "shape": [2, 18], "data": bytes(2 * 18 * 4)}


def test_a_hand_written_message_decodes():
    """What a server in another language would send."""
    data = msgpack.packb(
        {"type": "action", "server_time_ms": 3, "action": {"__ndarray__": True, "dtype": "<f4", "shape": [1, 18], "data": np.full(18, 0.5, "<f4").tobytes()}},
        use_bin_type=True,
    )
    message = protocol.parse(data, ("action",))
    assert message["action"].shape == (1, 18) and np.all(message["action"] == 0.5)


@pytest.mark.parametrize(
    "value",
    [
        np.array([object(), 1], dtype=object),
        np.array(["a", "b"]),
        np.array([1 + 2j]),
        object(),
        {1, 2},
        np.zeros((1,) * 9, dtype=np.float32),
    ],
    ids=["object-array", "str-array", "complex", "object", "set", "too-many-dims"],
)
def test_unencodable_values_are_refused(value):
    with pytest.raises(ProtocolError):
        protocol.encode(protocol.act_message({"x": value}))


def test_pickle_is_never_accepted():
    pickled = pickle.dumps({"type": "action", "action": np.zeros(18)})
    with pytest.raises(ProtocolError, match="msgpack"):
        protocol.decode(pickled)
    # msgpack-numpy style: an object array smuggled as pickled bytes
    smuggled = msgpack.packb(
        {"type": "action", "server_time_ms": 1.0, "action": {"__ndarray__": True, "dtype": "|O", "shape": [1], "data": pickle.dumps([1])}},
        use_bin_type=True,
    )
    with pytest.raises(ProtocolError, match="dtype '\\|O' is not accepted"):
        protocol.decode(smuggled)


def test_extension_types_are_refused():
    data = msgpack.packb({"type": "act", "observation": msgpack.ExtType(42, b"\x80\x04")}, use_bin_type=True)
    with pytest.raises(ProtocolError, match="extension type 42"):
        protocol.decode(data)


def test_the_timestamp_extension_is_refused_too():
    """msgpack decodes extension -1 (timestamp) itself, without the ext hook."""
    data = msgpack.packb({"type": "act", "observation": {"t": [msgpack.Timestamp(1, 2)]}}, use_bin_type=True)
    with pytest.raises(ProtocolError, match="extension type -1"):
        protocol.decode(data)


@pytest.mark.parametrize("dtype", ["|b1", "<c8"])
def test_boolean_and_complex_actions_are_refused(dtype):
    raw = {"type": "action", "server_time_ms": 1.0,
           "action": {"__ndarray__": True, "dtype": dtype, "shape": [1, 18], "data": bytes(18 * np.dtype(dtype).itemsize)}}
    with pytest.raises(ProtocolError, match="real-valued|not accepted"):
        protocol.parse(msgpack.packb(raw, use_bin_type=True), ("action",))


@pytest.mark.parametrize(
    "array, match",
    [
        ({"__ndarray__": True, "dtype": "<f4", "shape": [2, 18], "data": bytes(10)}, "needs 144 bytes, got 10"),
        ({"__ndarray__": True, "dtype": ">f4", "shape": [1], "data": bytes(4)}, "dtype '>f4' is not accepted"),
        ({"__ndarray__": True, "dtype": "<f4", "shape": [-1], "data": bytes(4)}, "shape must be"),
        ({"__ndarray__": True, "dtype": "<f4", "shape": "18", "data": bytes(72)}, "shape must be"),
        ({"__ndarray__": True, "dtype": "<f4", "shape": [18], "data": "text"}, "data must be msgpack bin"),
        ({"__ndarray__": True, "dtype": "<f4", "shape": [18]}, "exactly"),
    ],
)
def test_malformed_arrays_are_refused(array, match):
    data = msgpack.packb({"type": "action", "server_time_ms": 1.0, "action": array}, use_bin_type=True)
    with pytest.raises(ProtocolError, match=match):
        protocol.decode(data)


@pytest.mark.parametrize(
    "message, expected, match",
    [
        ({"type": "hello"}, None, "unknown message type 'hello'"),
        ({"no": "type"}, None, "unknown message type None"),
        ({"type": "action", "server_time_ms": 1.0}, None, "missing 'action'"),
        ({"type": "action", "action": [0.0] * 18, "server_time_ms": 1.0}, None, "'action' must be ndarray"),
        ({"type": "action", "action": np.zeros(18, np.float32), "server_time_ms": "1"}, None, "server_time_ms"),
        ({"type": "metadata", "protocol": "dyana/0", "policy": "p", "action_horizon": 1, "privileged": False}, None, "dyana/0"),
        ({"type": "metadata", "protocol": "dyana/1", "policy": "p", "action_horizon": 0, "privileged": False}, None, "action_horizon"),
        ({"type": "metadata", "protocol": "dyana/1", "policy": "p", "action_horizon": True, "privileged": False}, None, "action_horizon"),
        ({"type": "ready"}, ("action",), "expected a action message, got 'ready'"),
    ],
)
def test_malformed_messages_are_refused(message, expected, match):
    data = msgpack.packb(message, use_bin_type=True, default=protocol._pack_default)
    with pytest.raises(ProtocolError, match=match):
        protocol.parse(data, expected)


def test_undecodable_input_names_the_problem():
    with pytest.raises(ProtocolError, match="text frame"):
        protocol.decode('{"type": "act"}')
    with pytest.raises(ProtocolError, match="not a msgpack message"):
        protocol.decode(b"\xc1")
    with pytest.raises(ProtocolError, match="must be a msgpack map"):
        protocol.decode(msgpack.packb([1, 2]))
    with pytest.raises(ProtocolError, match="map keys must be strings"):
        protocol.decode(msgpack.packb({1: 2}))


def test_protocol_errors_are_policy_errors():
    assert issubclass(ProtocolError, PolicyError)
