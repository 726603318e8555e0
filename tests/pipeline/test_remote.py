"""Remote policies: `pipeline serve` in a subprocess on a free port, `RemotePolicy`
and `pipeline eval --policy ws://...`; the same policy over the wire gives
byte-identical rollouts to the in-process one."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from websockets.sync.client import connect

from generators.recipe import spec_for
from pipeline.jobs.evaluate import evaluate
from pipeline.loop.env import horizon
from pipeline.loop.rollout import task_for
from pipeline.loop.wrappers import loop_env
from pipeline.policies.base import make_policy
from pipeline.remote import protocol
from pipeline.remote.client import RemotePolicy
from schemas.errors import PolicyError
from tests.pipeline.in_thread import served
from tests.shard_files import shard_bytes

BIN = Path(sys.executable).parent
RESOLUTION = 48
POLICY = "predictive"


def start_server(policy: str, *extra: str) -> tuple[subprocess.Popen, str]:
    """`pipeline serve --port 0` in a subprocess; returns it and the URL it printed."""
    proc = subprocess.Popen(
        [str(BIN / "pipeline"), "serve", "--policy", policy, "--host", "127.0.0.1", "--port", "0", *extra],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    killer = threading.Timer(60, proc.kill)
    killer.start()
    try:
        for line in proc.stderr:
            found = re.search(r"serving \S+ on (ws://127\.0\.0\.1:\d+)", line)
            if found:  # keep draining stderr so the server never blocks on a full pipe
                proc.drain = threading.Thread(target=lambda: [None for _ in proc.stderr], daemon=True)
                proc.drain.start()
                return proc, found.group(1)
        raise AssertionError(f"`pipeline serve` exited with {proc.wait()} before listening")
    finally:
        killer.cancel()


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="module")
def server():
    proc, url = start_server(POLICY)
    yield url
    proc.terminate()
    assert proc.wait(timeout=20) == 0
    proc.drain.join(timeout=10)
    proc.stderr.close()


def _shard_bytes(run: Path) -> dict[str, bytes]:
    return shard_bytes(run)


def test_remote_rollouts_are_byte_identical_to_in_process(server, tmp_path):
    episodes = dict(episodes=4, resolution=RESOLUTION, shard_size=2, progress=False, summary=False)
    local = evaluate(POLICY, "test-1k", tmp_path / "local", workers=0, **episodes)
    remote = evaluate(server, "test-1k", tmp_path / "remote", workers=2, **episodes)
    assert _shard_bytes(tmp_path / "remote") == _shard_bytes(tmp_path / "local")
    assert remote.hash == local.hash
    assert (tmp_path / "remote" / "catalog.json").read_bytes() == (tmp_path / "local" / "catalog.json").read_bytes()
    assert remote.extra["policy"] == POLICY


def test_remote_policy_speaks_like_the_local_one(server):
    spec = spec_for("test-1k", 2)
    env = loop_env(resolution=RESOLUTION)
    obs, _ = env.reset(options={"spec": spec})
    local = make_policy(POLICY)
    task = task_for(spec, RESOLUTION, False, horizon(spec))
    with RemotePolicy(server, timeout_s=30) as remote:
        assert (remote.name, remote.action_horizon, remote.privileged) == (local.name, local.action_horizon, local.privileged)
        remote.reset(task)
        local.reset(task)
        for _ in range(5):
            got, want = remote.act(obs), local.act(obs)
            assert got.dtype == np.float32
            assert got.tobytes() == np.asarray(want, dtype=np.float32).reshape(got.shape).tobytes()
            obs = env.step(got.reshape(-1, 18)[0])[0]
        timing = remote.timing()
    assert timing["calls"] == 5 and timing["round_trip_ms"] >= timing["server_ms"] > 0


def test_server_answers_bad_requests_with_errors_and_stays_usable(server):
    with connect(server, compression=None, max_size=protocol.MAX_MESSAGE_BYTES) as ws:
        hello = protocol.parse(ws.recv(timeout=10))
        assert hello["type"] == "metadata" and hello["protocol"] == "dyana/1" and hello["policy"] == POLICY
        ws.send("not msgpack")
        assert "bad request" in protocol.parse(ws.recv(timeout=10))["message"]
        ws.send(protocol.encode(protocol.act_message({"frame_index": 0})))
        assert "act before reset" in protocol.parse(ws.recv(timeout=10))["message"]
        ws.send(protocol.encode(protocol.reset_message({"text": "t", "fps": 20, "observe_frames": 0, "horizon": 10,
                                                        "resolution": RESOLUTION, "hand": "right"})))
        assert protocol.parse(ws.recv(timeout=10))["type"] == "ready"
        ws.send(protocol.encode(protocol.act_message({"frame_index": 0})))  # missing keys: the policy raises
        reply = protocol.parse(ws.recv(timeout=10))
        assert reply["type"] == "error" and "policy act raised" in reply["message"]


def test_remote_errors_become_policy_errors(server):
    with RemotePolicy(server) as remote:
        with pytest.raises(PolicyError, match="act before reset"):
            remote.act({"frame_index": 0})
        with pytest.raises(PolicyError, match="unusable after an earlier failure"):
            remote.reset({})
    with pytest.raises(PolicyError, match="cannot connect to the policy server"):
        RemotePolicy(f"ws://127.0.0.1:{free_port()}", timeout_s=1)


def test_eval_of_an_unreachable_server_is_bad_input(tmp_path):
    url = f"ws://127.0.0.1:{free_port()}"
    result = subprocess.run(
        [str(BIN / "pipeline"), "eval", "--policy", url, "--episodes", "1", "--out", str(tmp_path / "run")],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 2
    assert url in result.stderr and "cannot connect" in result.stderr and "Traceback" not in result.stderr


def test_serve_refuses_an_unknown_policy():
    result = subprocess.run(
        [str(BIN / "pipeline"), "serve", "--policy", "nosuch", "--port", "0"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 2
    assert "unknown policy 'nosuch'" in result.stderr


def test_latency_over_loopback_is_small(server):
    """One act round trip with a 48 px image: the protocol adds little to the policy's own time."""
    spec = spec_for("test-1k", 0)
    env = loop_env(resolution=RESOLUTION)
    obs, _ = env.reset(options={"spec": spec})
    with RemotePolicy(server) as remote:
        remote.reset(task_for(spec, RESOLUTION, False, horizon(spec)))
        for _ in range(20):
            remote.act(obs)
        timing = remote.timing()
    overhead = timing["round_trip_ms"] - timing["server_ms"]
    print(f"loopback: {timing['round_trip_ms']:.2f} ms round trip, {overhead:.2f} ms protocol overhead")
    assert overhead < 50.0


def test_the_documented_example_server_works(tmp_path):
    """The wire-protocol page's 30-line server, run as written (on a free port), gives the frames of `still`."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "reference" / "wire-protocol.md").read_text()
    section = text[text.index("## A server in 30 lines"):]
    code = section[section.index("```python\n") + len("```python\n"):]
    code = code[: code.index("```")]
    port = free_port()
    (tmp_path / "server.py").write_text(code.replace("8765", str(port)))
    proc = subprocess.Popen([sys.executable, "server.py"], cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert proc.poll() is None, proc.stderr.read()
                assert time.monotonic() < deadline, "the example server did not start"
                time.sleep(0.1)
        common = dict(episodes=3, resolution=RESOLUTION, shard_size=3, workers=0, progress=False, summary=False)
        mine = evaluate(f"ws://127.0.0.1:{port}", "test-1k", tmp_path / "mine", **common)
        evaluate("still", "test-1k", tmp_path / "still", **common)
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        proc.stderr.close()
    assert mine.extra["policy"] == "my-still"
    frames = mine.shards[0].files["frames"].path
    assert (tmp_path / "mine" / frames).read_bytes() == (tmp_path / "still" / frames).read_bytes()


def test_serve_refuses_a_policy_that_cannot_describe_itself_before_listening(tmp_path):
    module = tmp_path / "nameless_policy.py"
    module.write_text(
        "class Nameless:\n    name = ''\n    action_horizon = 0\n    privileged = False\n"
        "    def reset(self, task): pass\n    def act(self, obs): return None\n"
    )
    result = subprocess.run(
        [str(BIN / "pipeline"), "serve", "--policy", "nameless_policy:Nameless", "--port", "0"],
        capture_output=True, text=True, timeout=60, cwd=tmp_path,
    )
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "cannot be served" in result.stderr and "serving" not in result.stderr


def test_connections_beyond_the_limit_are_told_busy_and_big_requests_are_cut(tmp_path):
    """Memory is bounded: at most --max-connections sessions, requests of at most --max-message-mb."""
    import contextlib

    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    proc, url = start_server("still", "--max-connections", "2", "--max-message-mb", "1")
    try:
        with contextlib.ExitStack() as stack:
            first, second = (stack.enter_context(connect(url, max_size=None)) for _ in range(2))
            for ws in (first, second):
                assert protocol.decode(ws.recv(timeout=10))["type"] == "metadata"
            with connect(url, max_size=None) as third:
                busy = protocol.decode(third.recv(timeout=10))
                assert busy["type"] == "error" and "server busy: at most 2" in busy["message"]
                with pytest.raises(ConnectionClosed):
                    third.recv(timeout=10)
            first.send(bytes(2 << 20))
            with pytest.raises(ConnectionClosed) as closed:
                first.recv(timeout=10)
            assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009
        with connect(url, max_size=None) as again:  # the slots free up
            assert protocol.decode(again.recv(timeout=10))["type"] == "metadata"
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def test_clients_that_close_at_once_leave_no_threads_behind():
    """Each session's worker thread ends with its connection, even one closed before the
    metadata arrives: the server's thread count returns to where it started."""
    with served("still", max_connections=64) as url:
        with connect(url) as ws:  # one full session first: imports and threads settle
            assert protocol.decode(ws.recv(timeout=10))["type"] == "metadata"
        time.sleep(0.5)
        start = threading.active_count()
        def handshake_and_close():
            with connect(url):
                pass

        clients = [threading.Thread(target=handshake_and_close) for _ in range(50)]
        for client in clients:
            client.start()
        for client in clients:
            client.join(30)
        deadline = time.monotonic() + 10
        while threading.active_count() > start and time.monotonic() < deadline:
            time.sleep(0.1)
        assert threading.active_count() <= start, [t.name for t in threading.enumerate()]

