"""A run's processes end with it, a policy cannot reach Dyana's processes, and Ctrl-C or a
lost scheduler is one line.

The policies here are written into the test's folder as a module (``module:callable``)
and record their process ids, so that every process a test starts is checked, and
killed in the end whatever happens."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from catalog.store.manifest import load_manifest
from catalog.tables.parquet_io import read_episodes

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="process groups and /proc as on Linux")

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[2]
RESOLUTION = 32
INTERRUPTED = "interrupted; rerun the same command to resume"

POLICIES = '''
import json, os, signal, subprocess, time

from pipeline.policies.base import state_action

PIDS = {pids!r}
MARK = {mark!r}


class Lingering:
    """Like `still`, slowly; starts a child process of its own and records its processes."""

    name, action_horizon, privileged = "lingering", 1, False

    def __init__(self):
        self.child = subprocess.Popen(["sleep", "600"])
        with open(PIDS, "a") as f:
            f.write(json.dumps([os.getpid(), os.getppid(), self.child.pid]) + "\\n")

    def reset(self, task):
        pass

    def act(self, obs):
        time.sleep(0.05)
        return state_action(obs)


class Signalling(Lingering):
    """Like Lingering, quickly; at the third act of an episode it sends its parent process the
    first signal of DYANA_TEST_SIGNALS (names, comma-separated) not yet sent in the run: the
    first episode the first signal, and so on."""

    name = "signalling"

    def reset(self, task):
        self.calls = 0

    def act(self, obs):
        self.calls += 1
        if self.calls == 3:
            for name in os.environ["DYANA_TEST_SIGNALS"].split(","):
                if not os.path.exists(f"{{MARK}}-{{name}}"):
                    open(f"{{MARK}}-{{name}}", "w").close()
                    os.kill(os.getppid(), getattr(signal, name))
                    break
        return state_action(obs)
'''


def _alive(pid: int) -> bool:
    """A process that runs (a zombie has ended: its parent may be a container's init that never reaps)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state != "Z"


class Policies:
    """The module above in ``folder``; the process ids its policies recorded."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.pids_file = folder / "pids.jsonl"
        (folder / "dyana_hostile.py").write_text(
            textwrap.dedent(POLICIES.format(pids=str(self.pids_file), mark=str(folder / "signalled")))
        )

    def pids(self) -> list[int]:
        if not self.pids_file.exists():
            return []
        return [pid for line in self.pids_file.read_text().splitlines() for pid in json.loads(line)]

    def wait_started(self, proc: subprocess.Popen, timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while not self.pids() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert self.pids(), "the policy never started"

    def wait_gone(self, timeout: float = 20.0) -> list[int]:
        """The recorded processes still running after ``timeout`` s (none, once they end)."""
        deadline = time.monotonic() + timeout
        while (left := [pid for pid in self.pids() if _alive(pid)]) and time.monotonic() < deadline:
            time.sleep(0.05)
        return left

    def kill_all(self) -> None:
        for pid in self.pids():
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


@pytest.fixture
def policies(tmp_path):
    made = Policies(tmp_path)
    yield made
    made.kill_all()


def test_closing_a_launched_command_ends_its_whole_process_group(tmp_path):
    """The worker's side of the launcher, without an eval: the command's own child ends too."""
    from pipeline.remote.launcher import Launched

    child_file = tmp_path / "child"
    launched = Launched(["sh", "-c", f"sleep 600 & echo $! > {child_file}; wait"], dict(os.environ))
    pids: list[int] = []
    try:
        pids.append(launched.started() or 0)
        deadline = time.monotonic() + 20
        while not child_file.exists() or not child_file.read_text().strip():
            assert time.monotonic() < deadline, "the command never started its child"
            time.sleep(0.02)
        pids.append(int(child_file.read_text()))
        assert launched.check() is None and all(_alive(pid) for pid in pids)
        launched.close()
        assert not any(_alive(pid) for pid in pids)
    finally:
        for pid in pids:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


def test_a_launched_command_that_signals_its_parent_is_stopped_and_named(tmp_path):
    from pipeline.remote.launcher import Launched

    launched = Launched(["sh", "-c", "kill -TERM $PPID; sleep 600"], dict(os.environ))
    try:
        pid = launched.started()
        assert pid is not None
        deadline = time.monotonic() + 20
        while (stop := launched.check()) is None:
            assert time.monotonic() < deadline, "the signal was never seen"
            time.sleep(0.02)
        assert stop.by_parent and stop.text == (
            "sent SIGTERM to its parent process, which a policy must not do; it was stopped")
        assert not _alive(pid)
    finally:
        launched.close()


#: Runs the command after it as a terminal's foreground job starts: with SIGINT's default
#: action, even where this test run was started with SIGINT ignored (a shell's background
#: job: `cmd &`), which the command's Python would keep, taking no Ctrl-C at all.
FOREGROUND = [sys.executable, "-c", "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
              "os.execv(sys.argv[1], sys.argv[1:])"]


def _eval(policies: Policies, policy: str, workers: int, episodes: int, **env: str) -> subprocess.Popen:
    """``pipeline eval`` in a process group of its own: ``--workers N`` (a local Dask cluster:
    two shards, as a job of one shard runs in the driver), or 0 for the library's run in
    this process, without Dask."""
    out = str(policies.folder / "run")
    if workers:
        command = [str(BIN / "pipeline"), "eval", "--policy", f"dyana_hostile:{policy}", "--episodes", str(episodes),
                   "--shard-size", str(max(1, episodes // 2)), "--workers", str(workers), "--resolution", str(RESOLUTION),
                   "--out", out]
    else:
        command = [sys.executable, "-c", "from pipeline.jobs.evaluate import evaluate; evaluate("
                   f"'dyana_hostile:{policy}', 'test-1k', {out!r}, episodes={episodes}, workers=0, "
                   f"resolution={RESOLUTION}, shard_size={episodes}, progress=False)"]
    path = os.pathsep.join([str(policies.folder), str(ROOT), os.environ.get("PYTHONPATH", "")])
    return subprocess.Popen([*FOREGROUND, *command], cwd=policies.folder, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, env={**os.environ, "PYTHONPATH": path, **env})


def _stop(proc: subprocess.Popen) -> None:
    with contextlib.suppress(OSError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)


@pytest.mark.parametrize("workers", [0, 1])
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_killed_eval_leaves_no_process_behind(policies, sig, workers):
    """SIGKILL runs no clean-up, yet the policy's process and its own child end with the run."""
    proc = _eval(policies, "Lingering", workers, episodes=2)
    try:
        policies.wait_started(proc)
        os.killpg(proc.pid, sig)
        proc.communicate(timeout=60)
        assert policies.wait_gone() == []
    finally:
        _stop(proc)


#: The signals a policy sends its parent, one per episode of one run (a run each cost a
#: process start and a policy's for nothing more: each episode's policy process is new).
SIGNALS = ("SIGKILL", "SIGTERM", "SIGINT")


def test_a_policy_that_signals_its_parent_fails_only_its_episode(policies):
    """Episode i's policy sends its parent SIGNALS[i]: each fails that episode alone, named,
    and the run goes on (the episode after the last signal ends ok)."""
    from generators.recipe import spec_for

    proc = _eval(policies, "Signalling", 0, episodes=len(SIGNALS) + 1, DYANA_TEST_SIGNALS=",".join(SIGNALS))
    try:
        out, err = proc.communicate(timeout=120)
    finally:
        _stop(proc)
    assert proc.returncode == 0, err[-2000:]
    run = policies.folder / "run"
    manifest = load_manifest(run)
    rows = read_episodes(run / manifest.shards[0].files["episodes"].path, ["episode_index", "status", "error"]).to_pylist()
    assert [(row["episode_index"], row["status"]) for row in rows] == [(0, "error"), (1, "error"), (2, "error"), (3, "ok")], rows
    for index, sig in enumerate(SIGNALS):
        error = rows[index]["error"]
        assert error.startswith(f"frame {spec_for('test-1k', index).observe_frames + 2}: policy process "), error
        assert sig in error and "its parent" in error, error
    assert policies.wait_gone() == []


@pytest.mark.slow(cover="tests/pipeline/test_processes.py::test_a_policy_that_signals_its_parent_fails_only_its_episode")
def test_a_policy_that_signals_a_dask_worker_reaches_only_its_launcher(policies):
    """With ``--workers``, the parent a policy sees is not the Dask worker: the run keeps its
    workers, records the episode's fault and exits 0."""
    proc = _eval(policies, "Signalling", 1, episodes=2, DYANA_TEST_SIGNALS="SIGINT")
    try:
        out, err = proc.communicate(timeout=120)
    finally:
        _stop(proc)
    assert proc.returncode == 0 and "Traceback" not in err, err[-2000:]
    assert "1 error(s)" in out and "sent SIGINT to its parent process" in out, out
    assert policies.wait_gone() == []


def _lines(proc: subprocess.Popen) -> tuple[list[str], threading.Thread]:
    lines: list[str] = []
    stderr = proc.stderr
    assert stderr is not None
    reader = threading.Thread(target=lambda: lines.extend(stderr), daemon=True)
    reader.start()
    return lines, reader


def test_ctrl_c_during_eval_is_one_line_and_ends_every_process(policies):
    """SIGINT to the whole process group, Dask workers included, as a terminal sends it."""
    proc = _eval(policies, "Lingering", 1, episodes=2)
    lines, reader = _lines(proc)
    try:
        policies.wait_started(proc)
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=60)
        reader.join(10)
    finally:
        _stop(proc)
    text = "".join(lines)
    assert proc.returncode == 130, text
    assert text == f"pipeline eval: {INTERRUPTED}\n", text
    assert policies.wait_gone() == []


def _interrupted_build(out: str, env: dict[str, str] | None = None) -> tuple[int | None, list[str]]:
    """``pipeline build`` into ``out`` given Ctrl-C (SIGINT to its group) once it reported an
    episode: its exit code and the lines it printed other than progress."""
    command = [str(BIN / "pipeline"), "build", "--slice", "linear-fast", "--episodes", "8", "--shard-size", "2",
               "--workers", "1", "--resolution", str(RESOLUTION), "--out", out]
    proc = subprocess.Popen([*FOREGROUND, *command], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env={**os.environ, **(env or {})})
    lines, reader = _lines(proc)
    try:
        deadline = time.monotonic() + 120
        while not any(line.startswith("[") for line in lines) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # a first episode is done
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=60)
        reader.join(10)
    finally:
        _stop(proc)
    assert lines and lines[0].startswith("building linear-fast: "), lines  # how big, said first
    return proc.returncode, [line for line in lines[1:] if not line.startswith("[")]  # not the progress lines


def test_ctrl_c_during_build_is_one_line(tmp_path):
    code, said = _interrupted_build(str(tmp_path))
    assert code == 130 and said == [f"pipeline build: {INTERRUPTED}\n"], said


def test_a_lost_scheduler_or_a_task_whose_workers_died_is_one_error():
    from distributed import KilledWorker
    from distributed.client import FutureCancelledError

    from pipeline.jobs.tasks import dask_failure

    failure = dask_failure(FutureCancelledError("shard-000000-000002", "scheduler-connection-lost"), "tcp://10.0.0.9:8786")
    assert failure is not None
    assert str(failure).startswith("--scheduler 'tcp://10.0.0.9:8786': lost the connection to the Dask scheduler")
    assert dask_failure(ValueError("a task's own error"), "tcp://10.0.0.9:8786") is None
    died = dask_failure(KilledWorker("shard-000000-000002", None, 2), None)
    assert died is not None and str(died).startswith("task 'shard-000000-000002': each Dask worker that ran it died (3 tries")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.slow(cover="tests/pipeline/test_object_store.py::test_a_killed_remote_build_resumes_on_another_machine")
def test_killing_the_scheduler_mid_build_is_one_line_and_the_rerun_resumes_to_the_same_bytes(tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    scheduler = subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                  "--no-dashboard"], **quiet)
    worker = subprocess.Popen([str(BIN / "dask"), "worker", address, "--nthreads", "1", "--nworkers", "1",
                               "--no-dashboard", "--host", "127.0.0.1"], **quiet)
    build = None
    try:
        command = [str(BIN / "pipeline"), "build", "--slice", "linear-fast", "--episodes", "6", "--shard-size", "1",
                   "--resolution", str(RESOLUTION), "--scheduler", address, "--out", str(tmp_path), "--quiet"]
        build = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        state = tmp_path / "linear-fast" / ".build-state.json"
        deadline = time.monotonic() + 120
        while not state.exists() and build.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        scheduler.kill()
        _, err = build.communicate(timeout=120)
        assert build.returncode == 2 and err.count("\n") == 1 and "Traceback" not in err, err
        assert f"--scheduler '{address}': lost the connection to the Dask scheduler" in err, err
        resumed = subprocess.run([*command[:-5], "--workers", "1", "--out", str(tmp_path), "--quiet"],
                                 capture_output=True, text=True, timeout=300)
        reference = subprocess.run([*command[:-5], "--workers", "1", "--out", str(tmp_path / "ref"), "--quiet"],
                                   capture_output=True, text=True, timeout=300)
        assert resumed.returncode == 0 and reference.returncode == 0, resumed.stderr + reference.stderr
        assert resumed.stdout.split("(hash ")[1] == reference.stdout.split("(hash ")[1]
    finally:
        for proc in (build, worker, scheduler):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait(30)


@pytest.mark.slow(cover="tests/pipeline/test_processes.py::test_ctrl_c_during_build_is_one_line")
def test_ctrl_c_during_a_build_into_object_storage_is_one_line(tmp_path):
    from tests.s3_server import s3_server

    with s3_server("dyana-interrupted") as env:
        code, said = _interrupted_build("s3://dyana-interrupted/data", {**env, "DYANA_STAGING": str(tmp_path)})
    assert code == 130 and said == [f"pipeline build: {INTERRUPTED}\n"], said
