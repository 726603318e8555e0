"""The real openpi-client from PyPI as the peer, in its own venv (it pins numpy<2):
(a) openpi_client.websocket_client_policy drives `pipeline serve --protocol openpi` and gets
the in-process policy's actions byte for byte, and its error frame as openpi's RuntimeError;
(b) an openpi server packing with openpi_client's msgpack_numpy (openpi's own server lives
in the openpi training package, not the client) is evaluated with `pipeline eval --policy
openpi:ws://...` and rolls out byte-identical to the built-in `still`.
Marked ``peer``: deselected by default, run by .ci/run (the venv build takes 90-145 s once, warm pip cache)."""

from __future__ import annotations

import contextlib
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from generators.recipe import spec_for
from pipeline.jobs.evaluate import evaluate
from pipeline.loop.env import horizon
from pipeline.loop.rollout import task_for
from pipeline.loop.wrappers import loop_env
from pipeline.policies.base import make_policy
from pipeline.remote import openpi_wire
from pipeline.remote.openpi_keys import OpenpiConfig, request_for
from tests.peer_venv import peer_python
from tests.shard_files import shard_bytes

from .test_remote import RESOLUTION, start_server

pytestmark = pytest.mark.peer
VERSION = "0.1.2"
#: openpi-client 0.1.2 imports typing_extensions without declaring it (its users install it too).
ALSO = ("typing_extensions",)
SCRIPTS = Path(__file__).parent / "openpi_peer"
POLICY = "predictive"


@contextlib.contextmanager
def served_openpi() -> Iterator[str]:
    """`pipeline serve --protocol openpi` of POLICY for the block's duration; yields its URL and
    checks that it stops cleanly (exit 0) when terminated."""
    proc, url = start_server(POLICY, "--protocol", "openpi")
    try:
        yield url
    finally:
        proc.terminate()
        assert proc.wait(timeout=20) == 0
        proc.drain.join(timeout=10)
        proc.stderr.close()


@pytest.fixture(scope="module")
def python() -> Path:
    return peer_python("openpi-client", VERSION, ALSO)


def test_openpi_client_drives_pipeline_serve(python, tmp_path):
    spec = spec_for("test-1k", 3)
    env = loop_env(resolution=RESOLUTION)
    obs, _ = env.reset(options={"spec": spec})
    local = make_policy(POLICY)
    task = task_for(spec, RESOLUTION, False, horizon(spec))
    local.reset(task)
    requests, expected = [], []
    for step in range(6):
        requests.append(request_for(obs, task if step == 0 else None, OpenpiConfig()))
        action = np.asarray(local.act(obs), dtype=np.float32).reshape(-1, 18)
        expected.append(action)
        obs = env.step(action[0])[0]
    (tmp_path / "requests.msgpack").write_bytes(openpi_wire.encode({"requests": requests}))
    with served_openpi() as url:
        ran = subprocess.run([str(python), str(SCRIPTS / "client.py"), url, str(tmp_path / "requests.msgpack"),
                              str(tmp_path / "out.msgpack")], capture_output=True, text=True, timeout=120)
    assert ran.returncode == 0, ran.stderr
    out = openpi_wire.decode((tmp_path / "out.msgpack").read_bytes())
    assert out["metadata"]["policy"] == POLICY and out["metadata"]["keys"]["state"] == "observation/state"
    assert [a.tobytes() for a in out["actions"]] == [a.tobytes() for a in expected]
    assert "Error in inference server" in out["error"] and "bad request: request is missing 'observation/state'" in out["error"]


def test_pipeline_eval_drives_an_openpi_server(python, tmp_path):
    proc = subprocess.Popen([str(python), str(SCRIPTS / "server.py")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        killer = threading.Timer(60, proc.kill)
        killer.start()
        line = proc.stdout.readline()
        killer.cancel()
        assert line.startswith("listening "), (line, proc.stderr.read() if proc.poll() is not None else "")
        ref = f"openpi:ws://127.0.0.1:{int(line.split()[1])}?steps=1&extras=off"
        episodes = dict(episodes=3, resolution=RESOLUTION, shard_size=3, workers=0, progress=False, summary=False)
        local = evaluate("still", "test-1k", tmp_path / "local", **episodes)
        remote = evaluate(ref, "test-1k", tmp_path / "remote", **episodes)
    finally:
        proc.kill()
        proc.wait(timeout=20)
    assert shard_bytes(tmp_path / "remote") == shard_bytes(tmp_path / "local")
    assert remote.hash == local.hash and remote.extra["openpi"]["steps"] == 1


def test_the_guides_openpi_client_snippet_runs_with_the_real_client(python, tmp_path):
    """The guide's `needs openpi_client` block (skipped by the docs tests: Dyana's env has no
    openpi-client) runs here, in the peer venv, against `pipeline serve --protocol openpi`."""
    page = (Path(__file__).parents[2] / "docs" / "guides" / "openpi.md").read_text()
    block = page.split("<!-- docs-test: needs openpi_client -->\n```python\n", 1)[1].split("\n```", 1)[0]
    (tmp_path / "snippet.py").write_text(block)
    with served_openpi() as url:
        (tmp_path / "openpi.url").write_text(url + "\n")
        ran = subprocess.run([str(python), "snippet.py"], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.splitlines() == [
        "{'policy': 'predictive', 'action_horizon': 1, 'keys': {'image': 'observation/image', 'state': "
        "'observation/state', 'prompt': 'prompt', 'actions': 'actions'}}",
        "(1, 18)",
    ]
