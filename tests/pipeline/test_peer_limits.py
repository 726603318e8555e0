"""A hostile peer costs at most its own connection: what a request declares is bounded
(pipeline.remote.limits) before it is built, and a good client is still served while
hostile ones are connected. Each case is one the outside corpus found (issue 39)."""

from __future__ import annotations

import random
import time
import tracemalloc
from pathlib import Path

import msgpack
import numpy as np
import pytest
from websockets.sync.client import connect

from generators.recipe import spec_for
from pipeline.loop.env import horizon
from pipeline.loop.rollout import task_for
from pipeline.loop.wrappers import loop_env
from pipeline.remote import openpi_wire, protocol
from pipeline.remote.limits import MAX_NODES, LimitError, check_images, check_task, scan
from pipeline.remote.openpi_keys import OpenpiConfig, request_for
from pipeline.remote.protocol import ProtocolError

from .test_remote import RESOLUTION, start_server

#: 32 MiB of empty maps in one array: 33 million dicts (2.4 GB) if built.
EMPTY_MAPS = b"\xdd" + (32 << 20).to_bytes(4, "big") + b"\x80" * (32 << 20)
TASK = {"text": "t", "fps": 20, "observe_frames": 0, "horizon": 10, "resolution": RESOLUTION, "hand": "right"}


@pytest.mark.parametrize("decode", [protocol.decode, openpi_wire.decode], ids=["dyana/1", "openpi"])
def test_millions_of_empty_values_are_refused_without_building_them(decode):
    tracemalloc.start()
    try:
        start = time.perf_counter()
        with pytest.raises(ProtocolError, match=f"more than {MAX_NODES} values"):
            decode(EMPTY_MAPS)
        elapsed = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20 and elapsed < 2.0, (peak, elapsed)


@pytest.mark.parametrize("data, match", [
    (b"\x91" * 20 + b"\xc0", "more than 16 deep"),
    (b"\xdf\xff\xff\xff\xff", "more than its bytes"),
    (b"\xc6\x7f\xff\xff\xff", "more bytes than it holds"),
    (b"\xc0\xc0", "1 bytes follow the value"),
    (b"\xc1", "starts no value"),
    (b"", "ends early"),
])
def test_malformed_or_deep_messages_are_named(data, match):
    with pytest.raises(LimitError, match=match):
        scan(data)


def test_every_well_formed_message_passes_and_every_cut_one_fails():
    rng = random.Random(7)
    for _ in range(300):
        value = {"a": [rng.random(), rng.randint(-2**63, 2**64 - 1), "s" * rng.randint(0, 300), b"b" * rng.randint(0, 70_000),
                       None, True, {"k": [1] * rng.randint(0, 20)}], "m": {str(j): j for j in range(rng.randint(0, 40))}}
        data = msgpack.packb(value, use_bin_type=True)
        scan(data)
        with pytest.raises(LimitError):
            scan(data[: rng.randint(0, len(data) - 1)])


@pytest.mark.parametrize("decode, marker", [(protocol.decode, "__ndarray__"), (openpi_wire.decode, b"__ndarray__")],
                         ids=["dyana/1", "openpi"])
def test_an_empty_array_of_a_vast_declared_shape_is_refused(decode, marker):
    array = {marker: True, "dtype" if marker == "__ndarray__" else b"dtype": "|u1",
             "shape" if marker == "__ndarray__" else b"shape": [0, 2**40, 3], "data" if marker == "__ndarray__" else b"data": b""}
    with pytest.raises(ProtocolError, match="axis 1 has 1099511627776 entries"):
        decode(msgpack.packb({"type": "act", "observation": {"image": array}}, use_bin_type=True))


@pytest.mark.parametrize("field, value", [("resolution", 2**31), ("resolution", 1e9), ("resolution", 4),
                                          ("observe_frames", 10**6), ("horizon", -1), ("fps", 0), ("text", "x" * 20_000),
                                          ("intercept_time_s", float("inf"))])
def test_a_task_out_of_its_caps_is_named(field, value):
    with pytest.raises(LimitError, match=f"task {field}"):
        check_task(TASK | {field: value})
    check_task(TASK)


@pytest.mark.parametrize("shape, resolution, match", [
    ((20000, 1, 3), None, r"must be \(R, R, 3\)"),
    ((4000, 4000, 3), None, r"R in \[8, 1024\]"),
    ((64, 64, 3), RESOLUTION, "the task's resolution 48"),
])
def test_images_of_another_shape_than_the_tasks_are_refused(shape, resolution, match):
    with pytest.raises(LimitError, match=match):
        check_images({"image": np.zeros(shape, np.uint8)}, resolution)
    check_images({"image": np.zeros((RESOLUTION, RESOLUTION, 3), np.uint8)}, RESOLUTION)


def _peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


#: The documented cap (docs/reference/bad-input.md, "Policy servers"): a server's peak
#: resident memory while it refuses every request above, at the default --max-message-mb.
SERVER_MEMORY_CAP_MB = 768


def _stop(proc) -> None:
    proc.terminate()
    assert proc.wait(timeout=20) == 0
    proc.drain.join(timeout=10)
    proc.stderr.close()


def _good_request() -> dict:
    spec = spec_for("test-1k", 0)
    obs, _ = loop_env(resolution=RESOLUTION).reset(options={"spec": spec})
    return request_for(obs, task_for(spec, RESOLUTION, False, horizon(spec)), OpenpiConfig())


def test_openpi_server_refuses_hostile_requests_within_its_cap_while_serving_a_good_client():
    proc, url = start_server("still", "--protocol", "openpi")
    good = _good_request()
    bare = {k: v for k, v in good.items() if not k.startswith("dyana/")}  # openpi's own keys only
    hostile = [
        (EMPTY_MAPS, "more than 10000 values"),
        (openpi_wire.encode(bare | {"observation/image": np.zeros((20000, 1, 3), np.uint8)}), r"must be (R, R, 3)"),
        (openpi_wire.encode(bare | {"observation/image": np.zeros((4000, 4000, 3), np.uint8)}), "R in [8, 1024]"),
        (openpi_wire.encode(good | {"dyana/task": dict(good["dyana/task"], resolution=2**31)}), "task resolution"),
    ]
    try:
        with connect(url, compression=None, max_size=None) as idle:  # a hostile peer that holds its connection
            idle.recv(timeout=10)
            for data, reason in hostile:
                with connect(url, compression=None, max_size=None) as ws:
                    ws.recv(timeout=10)
                    ws.send(data)
                    text = ws.recv(timeout=30)
                    assert isinstance(text, str) and reason in openpi_wire.error_line(text), text
            with connect(url, compression=None, max_size=None) as ws:
                ws.recv(timeout=10)
                start = time.perf_counter()
                ws.send(openpi_wire.encode(good))
                assert openpi_wire.decode(ws.recv(timeout=30))["actions"].shape == (1, 18)
                assert time.perf_counter() - start < 10
        assert _peak_rss_mb(proc.pid) < SERVER_MEMORY_CAP_MB
    finally:
        _stop(proc)


def test_dyana_server_refuses_hostile_requests_within_its_cap_and_stays_usable():
    proc, url = start_server("still")
    try:
        with connect(url, compression=None, max_size=None) as ws:
            ws.recv(timeout=10)
            ws.send(EMPTY_MAPS)
            assert "more than 10000 values" in protocol.parse(ws.recv(timeout=10))["message"]
            ws.send(protocol.encode(protocol.reset_message(TASK | {"resolution": 2**31})))
            assert "task resolution must be an integer in [8, 1024]" in protocol.parse(ws.recv(timeout=10))["message"]
            ws.send(protocol.encode(protocol.reset_message(TASK)))
            assert protocol.parse(ws.recv(timeout=10))["type"] == "ready"
            ws.send(protocol.encode(protocol.act_message({"image": np.zeros((4000, 4000, 3), np.uint8)})))
            assert "R in [8, 1024]" in protocol.parse(ws.recv(timeout=10))["message"]
            ws.send(protocol.encode(protocol.act_message({"image": np.zeros((64, 64, 3), np.uint8)})))
            assert "the task's resolution 48" in protocol.parse(ws.recv(timeout=10))["message"]
        assert _peak_rss_mb(proc.pid) < SERVER_MEMORY_CAP_MB
    finally:
        _stop(proc)
