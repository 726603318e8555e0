"""Faults fail their own episode only: NaN/inf or wrong-shape actions, an exception, a
policy past its deadline, a dropped connection. The episode is recorded with status
``error`` and the reason, the frames up to the fault are kept, the run completes with
every episode, the summary counts the errors, and `scoring eval` reads the run."""

from __future__ import annotations

import asyncio
import io
import json
import re
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from catalog.store.manifest import load_manifest
from catalog.tables.parquet_io import read_episodes, read_frames
from catalog.tables.shard import ShardWriter
from generators.recipe import spec_for
from pipeline.jobs.evaluate import evaluate, summarize
from pipeline.jobs.replay import replay
from pipeline.loop.fault_text import split_reason
from pipeline.loop.rollout import run_episode
from pipeline.loop.wrappers import loop_env
from pipeline.policies.base import state_action
from pipeline.remote import protocol

from .faulty_policies import FAULT_CALL, HANG_S, Single

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[2]
RESOLUTION = 48
DEADLINE_S = 0.5
SPEC = spec_for("test-1k", 2)  # observe-before-act: 18 observe frames

REASONS = {
    "nan": r"frame \d+: action contains NaN/inf at row 0, column 4 \(value nan\)",
    "inf": r"frame \d+: action contains NaN/inf at row 1, column 0 \(value inf\)",
    "shape": r"frame \d+: action must have shape \(18,\) or \(H, 18\) with H >= 1, got \(17,\)",
    "raise": r"frame \d+: policy act raised ValueError: the model diverged",
    "tensor": r"frame \d+: action is not a numeric array \(Unconvertible: RuntimeError: Can't call numpy\(\) on Tensor that requires grad\)",
    "complex": r"frame \d+: action is not a real array \(complex values: complex64\)",
    "hang": rf"frame \d+: policy act exceeded its deadline of {DEADLINE_S:g} s",
    "reset": r"frame 18: policy reset raised RuntimeError: cannot load the weights",
}


@pytest.fixture(scope="module")
def env():
    return loop_env(resolution=RESOLUTION)


@pytest.mark.parametrize("fault", sorted(REASONS))
def test_each_fault_fails_the_episode_and_keeps_its_frames(env, fault, tmp_path):
    policy = type("P", (Single,), {"fault": fault})()
    result = run_episode(env, policy, SPEC, DEADLINE_S)
    assert result.status == "error"
    reason, frames = split_reason(result.error)
    assert re.fullmatch(REASONS[fault], reason), result.error
    if fault in ("raise", "reset"):  # the traceback is kept, the policy's frames only, file names only
        assert frames and "faulty_policies.py:" in frames[-1] and "/" not in result.error
        assert not any("rollout.py" in line or "worker_thread.py" in line for line in frames)
    first_acting = SPEC.observe_frames
    if fault == "reset":
        assert result.calls == 0 and result.frames.num_frames == first_acting + 1
    else:  # two good steps, then the fault at the third call: nothing of it executed
        assert result.calls == FAULT_CALL and result.steps == FAULT_CALL - 1
        assert result.frames.num_frames == first_acting + FAULT_CALL
        assert result.error.startswith(f"frame {first_acting + FAULT_CALL - 1}:")
    assert len(result.images) == result.frames.num_frames
    assert np.isfinite(result.frames.action).all()
    with ShardWriter(tmp_path, SPEC.episode_index, SPEC.episode_index + 1, {"resolution": RESOLUTION}, rollout=True) as w:
        w.add_episode(SPEC, result.frames, result.images, policy=policy.name, status=result.status, error=result.error)
    assert w.record.frames == result.frames.num_frames


@pytest.mark.parametrize("ref", ["ComplexFault", "RaiseFault"])
def test_a_child_process_refuses_what_in_process_refuses_in_the_same_words(env, ref):
    """The default child process and --in-process agree: a complex action (whose cast would
    drop the imaginary part) fails the episode both ways, and the reasons are equal."""
    from pipeline.policies.base import make_policy
    from pipeline.remote.isolated import IsolatedPolicy

    local = run_episode(env, make_policy(f"tests.pipeline.faulty_policies:{ref}"), SPEC, 5.0)
    child_policy = IsolatedPolicy(f"tests.pipeline.faulty_policies:{ref}", timeout_s=30.0)
    try:
        child = run_episode(env, child_policy, SPEC, 30.0)
    finally:
        child_policy.close()
    assert local.status == child.status == "error"
    assert child.error == local.error and child.calls == local.calls == FAULT_CALL
    assert child.policy_s < 1.0  # the policy's own error: no wait for its process to end


@pytest.mark.parametrize("isolate", [False, True])
def test_a_raising_policy_is_reported_as_a_policy_with_its_traceback(isolate, tmp_path):
    """Nothing is remote: the summary says "policy", the traceback is in the record (and
    printed with --in-process), and the failed call's time is not counted as act time."""
    printed = io.StringIO()
    manifest = evaluate(
        "tests.pipeline.faulty_policies:RaiseFault", "test-1k", tmp_path / "run", episodes=1, workers=0,
        resolution=RESOLUTION, progress=False, stream=printed, isolate=isolate,
    )
    text = printed.getvalue()
    assert "remote" not in text, text
    assert re.search(r"error in episode 0: frame \d+: policy act raised ValueError: the model diverged\n", text), text
    assert ("faulty_policies.py:" in text) == (not isolate), text
    per_act = float(re.search(r"policy ([\d.]+) ms per act", text).group(1))
    assert per_act < 500, text
    row = read_episodes(tmp_path / "run" / manifest.shards[0].files["episodes"].path, ["error"]).to_pylist()[0]
    assert split_reason(row["error"])[1][-1].startswith("  faulty_policies.py:")


def test_terminal_escapes_from_a_policy_are_printed_as_escapes(tmp_path):
    printed = io.StringIO()
    evaluate(
        "tests.pipeline.faulty_policies:Escapes", "test-1k", tmp_path / "run", episodes=1, workers=0,
        resolution=RESOLUTION, progress=False, stream=printed, isolate=False,
    )
    text = printed.getvalue()
    assert "\x1b" not in text, repr(text)
    assert "evaluated evil\\x1b[2J\\nname on test-1k" in text
    assert "raised RuntimeError: \\x1b[2J\\x1b[31mclear\\nscreen" in text


def test_a_hung_call_does_not_hold_the_run(env):
    import time

    start = time.monotonic()
    result = run_episode(env, type("P", (Single,), {"fault": "hang"})(), SPEC, DEADLINE_S)
    assert result.status == "error"
    assert time.monotonic() - start < HANG_S


def test_a_faulty_run_records_every_episode_and_counts_the_errors(tmp_path):
    """Through the CLI with Dask: one policy with a different fault in six of eight episodes.
    Both shards on one Dask worker (a second worker process cost its start, ~3 CPU s, for no
    other check: tests/pipeline/test_build.py builds on two)."""
    run = tmp_path / "run"
    result = subprocess.run(
        [str(BIN / "pipeline"), "eval", "--policy", "tests.pipeline.faulty_policies:Mixed", "--episodes", "8",
         "--shard-size", "4", "--workers", "1", "--deadline", str(DEADLINE_S), "--resolution", str(RESOLUTION),
         "--out", str(run), "--quiet", "--in-process"],
        capture_output=True, text=True, timeout=300, cwd=ROOT,
    )
    assert result.returncode == 0, result.stderr
    assert "evaluated mixed-faults on test-1k: 8 episodes" in result.stdout
    assert "6 error(s)" in result.stdout
    manifest = load_manifest(run)
    assert manifest.episodes == 8 and manifest.extra["policy"] == "mixed-faults"
    rows = []
    for shard in manifest.shards:
        rows += read_episodes(run / shard.files["episodes"].path, ["episode_index", "status", "error"]).to_pylist()
    by_index = {row["episode_index"]: row for row in rows}
    assert sorted(by_index) == list(range(8))
    assert [by_index[i]["status"] for i in range(8)] == ["ok"] + ["error"] * 6 + ["ok"]
    faults = {1: "nan", 2: "inf", 3: "shape", 4: "raise", 5: "hang", 6: "reset"}
    for index, fault in faults.items():
        pattern = REASONS[fault] if fault != "reset" else r"frame \d+: policy reset raised RuntimeError: cannot load the weights"
        assert re.fullmatch(pattern, split_reason(by_index[index]["error"])[0]), (index, by_index[index]["error"])
    frames = read_frames(run / manifest.shards[1].files["frames"].path, ["episode_index"])
    counts = np.bincount(frames.column("episode_index").to_numpy() - 4, minlength=4)
    assert counts[2] == spec_for("test-1k", 6).observe_frames + 1  # reset failed: observe + first frame
    assert summarize(run).errors == 6

    scored = subprocess.run([str(BIN / "scoring"), "eval", str(run), "--json"], capture_output=True, text=True, timeout=120)
    assert scored.returncode == 0, scored.stderr
    report = json.loads(scored.stdout)
    assert report["episodes"] == 8 and report["errors"] == 6
    replay(run)  # faulty runs replay too: the recorded actions reproduce every frame


# --- a misbehaving server ---------------------------------------------------------------

#: Episode index -> what the server does on that episode's third act.
SERVER_FAULTS = {0: "twice", 1: "close", 2: "abort", 3: "garbage", 4: "error"}


async def _misbehave(ws) -> None:
    await ws.send(protocol.encode(protocol.metadata_message("flaky", 1, True)))
    episode, calls = None, 0
    async for data in ws:
        message = protocol.parse(data)
        if message["type"] == "reset":
            episode, calls = json.loads(message["task"]["spec"])["episode_index"], 0
            await ws.send(protocol.encode({"type": "ready"}))
            continue
        calls += 1
        fault = SERVER_FAULTS.get(episode) if calls == FAULT_CALL else None
        if fault == "close":
            await ws.close(1011, "model crashed")
            return
        if fault == "abort":
            ws.transport.abort()
            return
        if fault == "twice":  # one spare reply: it must fail this episode, not the next
            reply = protocol.encode(protocol.action_message(state_action(message["observation"]), 0.1))
            await ws.send(reply)
            await ws.send(reply)
        elif fault == "garbage":
            await ws.send(b"\xc1 not msgpack")
        elif fault == "error":
            await ws.send(protocol.encode(protocol.error_message("CUDA out of memory")))
        else:
            await ws.send(protocol.encode(protocol.action_message(state_action(message["observation"]), 0.1)))


@pytest.fixture(scope="module")
def flaky_server():
    from websockets.asyncio.server import serve

    ready, holder = threading.Event(), {}

    async def main():
        holder["stop"] = asyncio.get_running_loop().create_future()
        async with serve(_misbehave, "127.0.0.1", 0, compression=None, max_size=protocol.MAX_MESSAGE_BYTES) as server:
            holder["url"] = f"ws://127.0.0.1:{server.sockets[0].getsockname()[1]}"
            holder["loop"] = asyncio.get_running_loop()
            ready.set()
            await holder["stop"]

    thread = threading.Thread(target=lambda: asyncio.run(main()), daemon=True)
    thread.start()
    assert ready.wait(10)
    yield holder["url"]
    holder["loop"].call_soon_threadsafe(holder["stop"].set_result, None)
    thread.join(10)


def test_dropped_connections_and_bad_replies_fail_only_their_episode(flaky_server, tmp_path):
    printed = io.StringIO()
    manifest = evaluate(
        flaky_server, "test-1k", tmp_path / "run", episodes=6, workers=0, resolution=RESOLUTION, shard_size=3,
        deadline_s=5.0, progress=False, stream=printed,
    )
    assert manifest.episodes == 6 and manifest.extra["policy"] == "flaky"
    rows = []
    for shard in manifest.shards:
        rows += read_episodes(tmp_path / "run" / shard.files["episodes"].path, ["episode_index", "status", "error"]).to_pylist()
    errors = {row["episode_index"]: row["error"] for row in rows if row["status"] == "error"}
    assert sorted(errors) == [0, 1, 2, 3, 4]
    assert re.fullmatch(r"frame \d+: remote policy: protocol error: a spare action reply that answers no request", errors[0])
    assert "remote policy: connection closed (code 1011, model crashed)" in errors[1]
    assert "remote policy: connection closed" in errors[2]
    assert "remote policy: protocol error: not a msgpack message" in errors[3]
    assert "remote policy: server error: CUDA out of memory" in errors[4]
    for index, reason in errors.items():
        if index == 0:  # found at a later act (the next one, unless the spare is slow to arrive)
            assert int(reason.split(":")[0].split()[1]) >= spec_for("test-1k", 0).observe_frames + FAULT_CALL, reason
            continue
        assert reason.startswith(f"frame {spec_for('test-1k', index).observe_frames + FAULT_CALL - 1}:"), reason
        assert "127.0.0.1" not in reason  # recorded reasons never name the host
    assert "5 error(s)" in printed.getvalue()
    assert "error in episode 1: frame" in printed.getvalue()


def test_a_policy_that_kills_its_own_process_fails_only_its_episode(tmp_path, monkeypatch, capfd):
    """By default a module:callable runs in a child process: os._exit, sys.exit and
    KeyboardInterrupt end that process only, each episode records how, the run completes,
    and megabytes the policy prints never reach eval's output (this process's file
    descriptors 1 and 2, which the command's entry point writes to here: a process of
    its own cost its start)."""
    from pipeline.cli import main

    run = tmp_path / "run"
    monkeypatch.setenv("DYANA_TEST_COUNTER", str(tmp_path / "counter"))
    monkeypatch.chdir(ROOT)
    code = main(["eval", "--policy", "tests.pipeline.faulty_policies:Dying", "--episodes", "5", "--shard-size", "5",
                 "--workers", "1", "--resolution", str(RESOLUTION), "--out", str(run), "--quiet"])
    result = capfd.readouterr()
    assert code == 0, result.err[-2000:]
    assert "noise" not in result.out and "noise" not in result.err and len(result.out) < 5000
    assert "evaluated dying on test-1k: 5 episodes" in result.out and "3 error(s)" in result.out
    manifest = load_manifest(run)
    rows = read_episodes(run / manifest.shards[0].files["episodes"].path, ["episode_index", "status", "error"]).to_pylist()
    assert [r["status"] for r in rows] == ["ok", "error", "error", "error", "ok"]
    assert "policy process exited with code 3" in rows[1]["error"]
    assert "policy process exited with code 4" in rows[2]["error"]
    assert "policy process exited with code" in rows[3]["error"]
    assert [p.name for p in run.rglob("*") if p.name.startswith(".")] == [".lock"]  # no temporary; the lock stays


def test_an_eval_where_every_episode_failed_is_written_then_exits_3(tmp_path, capsys):
    """The command's entry point (what the console script calls) in this process: a process
    of its own cost its start (the CLI runs above run the command as a process)."""
    from pipeline.cli import main

    out = tmp_path / "run"
    code = main(["eval", "--policy", "tests.pipeline.faulty_policies:RaiseFault", "--slice", "test-1k", "--episodes", "2",
                 "--workers", "1", "--resolution", str(RESOLUTION), "--quiet", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 3, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert re.search(r"error: every episode failed \(2 of 2\); the first, episode 0: frame \d+: policy act raised "
                     r"ValueError: the model diverged", err), err
    assert (out / "catalog.json").is_file()


def test_a_reply_over_the_limit_is_named_as_such(env):
    """Before: 'policy process: connection closed (no close frame received)', which did not
    say that the policy's 14 MB reply was over the client's 1 MiB."""
    from pipeline.remote.isolated import IsolatedPolicy

    child_policy = IsolatedPolicy("tests.pipeline.faulty_policies:HugeReply", timeout_s=30.0)
    try:
        child = run_episode(env, child_policy, SPEC, 30.0)
    finally:
        child_policy.close()
    assert child.status == "error"
    assert re.search(r"frame \d+: policy process: connection closed \(code 1009, a reply over 1 MiB\)", child.error), child.error
