"""The job runner shared by build and eval: one job per folder, resume, up to date,
the lock, worker defaults. Jobs here write tiny fake shards in this process."""

from __future__ import annotations

import hashlib
import itertools
import os
import re
import subprocess
from pathlib import Path

import pytest

from catalog.store.manifest import load_manifest
from catalog.store.records import shard_paths
from pipeline.jobs import tasks as task_module
from pipeline.jobs.lock import FolderBusy, folder_lock
from pipeline.jobs.runner import Execution, Job, JobResult, Storage, run_job
from pipeline.jobs.sink import ShardSink
from pipeline.jobs.state import STATE_FILE
from pipeline.jobs.tasks import ShardTask, default_workers, shard_ranges
from schemas.errors import SpecError
from tests.shard_files import shard_names

CALLS: list[int] = []


def fake_shard(task: ShardTask, payload: str, sink: ShardSink) -> dict:
    CALLS.append(task.first)
    files = {}
    with sink.writing() as folder:
        for kind, rel in shard_paths(task.first, task.end).items():
            data = f"{payload}:{kind}:{task.first}".encode()
            (folder / rel).parent.mkdir(exist_ok=True)
            (folder / rel).write_bytes(data)
            files[kind] = {"path": rel, "sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}
    return {"record": {"episodes": [task.first, task.end], "frames": task.end - task.first, "files": files}}


def job(episodes: int = 4, shard_size: int = 2, payload: str = "a", extra: dict | None = None) -> Job:
    tasks = tuple(ShardTask("linear-fast", a, b) for a, b in shard_ranges(episodes, shard_size))
    return Job("linear-fast", 1, {"resolution": 32}, extra or {}, tasks, fake_shard, payload, with_stats=False)


def run(folder: Path, job: Job, workers: int = 0, progress: bool = False, overwrite: bool = False) -> JobResult:
    """:func:`run_job` into the local ``folder``."""
    return run_job(job, Execution.of(workers, progress=progress), Storage(folder, overwrite))


@pytest.fixture(autouse=True)
def _calls():
    CALLS.clear()


def test_a_complete_identical_job_is_up_to_date(tmp_path):
    first = run(tmp_path, job(), workers=0, progress=False)
    assert not first.up_to_date and (first.shards_run, first.shards_resumed) == (2, 0) and CALLS == [0, 2]
    CALLS.clear()
    again = run(tmp_path, job(), workers=0, progress=False)
    assert again.up_to_date and CALLS == [] and again.manifest == first.manifest
    # no state left; the lock file stays (never unlinked) and is nothing a manifest lists
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock", "catalog.json", "episodes", "frames", "mcap"]


def test_a_rerun_removes_a_temp_named_with_its_own_pid(tmp_path):
    """A job killed mid-write leaves ``.<file>.tmp-PID``; a rerun in a fresh container may get
    that very pid (planted here as this process's own): it is a dead writer's, not ours."""
    run(tmp_path, job(), workers=0, progress=False)
    stray = [tmp_path / "frames" / f".000000-000002.parquet.tmp-{os.getpid()}", tmp_path / f".catalog.json.tmp-{os.getpid()}"]
    for path in stray:
        path.write_bytes(b"half")
    again = run(tmp_path, job(), workers=0, progress=False)
    assert again.up_to_date and not any(path.exists() for path in stray)


def test_a_damaged_shard_alone_is_redone(tmp_path):
    manifest = run(tmp_path, job(), workers=0, progress=False).manifest
    (tmp_path / manifest.shards[1].files["mcap"].path).write_bytes(b"tampered")
    CALLS.clear()
    again = run(tmp_path, job(), workers=0, progress=False)
    assert not again.up_to_date and CALLS == [2] and again.manifest.hash == manifest.hash
    assert (again.shards_run, again.shards_resumed) == (1, 1)


@pytest.mark.parametrize(
    "other, named",
    [
        (dict(episodes=2), "episodes 4 -> 2"),
        (dict(shard_size=1), "shards"),
        (dict(extra={"policy": "chase"}), 'extra.policy null -> "chase"'),
    ],
)
def test_another_job_is_refused_naming_the_difference_and_nothing_is_lost(tmp_path, other, named):
    run(tmp_path, job(), workers=0, progress=False)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    with pytest.raises(SpecError, match="another job") as caught:
        run(tmp_path, job(**other), workers=0, progress=False)
    assert named in str(caught.value) and "--overwrite" in str(caught.value)
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before
    replaced = run(tmp_path, job(**other), workers=0, progress=False, overwrite=True).manifest
    listed = {f.path for s in replaced.shards for f in s.files.values()}
    assert set(shard_names(tmp_path)) == listed


def interrupt_at_the_second_shard(folder: Path) -> None:
    """Run :func:`job` in ``folder`` until Ctrl-C (KeyboardInterrupt) stops it at its second shard."""
    def dies(task, payload, sink):
        if task.first == 2:
            raise KeyboardInterrupt
        return fake_shard(task, payload, sink)

    with pytest.raises(KeyboardInterrupt):
        run(folder, Job("linear-fast", 1, {"resolution": 32}, {}, job().tasks, dies, "a", with_stats=False),
                workers=0, progress=False)


def test_an_interrupted_run_of_another_job_is_refused(tmp_path, monkeypatch):
    interrupt_at_the_second_shard(tmp_path)
    assert (tmp_path / STATE_FILE).exists() and not (tmp_path / "catalog.json").exists()
    with pytest.raises(SpecError, match="unfinished run of another job"):
        run(tmp_path, job(episodes=2), workers=0, progress=False)
    CALLS.clear()
    run(tmp_path, job(), workers=0, progress=False)
    assert CALLS == [2]  # the same job resumes


def test_a_run_resumed_under_other_library_versions_rebuilds_every_shard(tmp_path, monkeypatch):
    """Shards of two installations never mix in one folder: the manifest records one set of
    versions, so a finished or interrupted run resumed with another pyarrow rebuilds all."""
    from catalog.store.versions import installed_versions
    from pipeline.jobs import runner, state

    interrupt_at_the_second_shard(tmp_path)
    other = {**installed_versions(), "pyarrow": "0.0.1"}
    monkeypatch.setattr(state, "installed_versions", lambda: other)
    monkeypatch.setattr(runner, "installed_versions", lambda: other)
    CALLS.clear()
    finished = run(tmp_path, job(), workers=0, progress=False)
    assert CALLS == [0, 2] and finished.shards_resumed == 0 and finished.manifest.versions["pyarrow"] == "0.0.1"
    CALLS.clear()
    assert run(tmp_path, job(), workers=0, progress=False).up_to_date and CALLS == []
    monkeypatch.undo()
    again = run(tmp_path, job(), workers=0, progress=False)
    assert not again.up_to_date and CALLS == [0, 2] and again.manifest.versions == installed_versions()


def test_a_second_process_on_the_folder_is_refused(tmp_path):
    with folder_lock(tmp_path):
        with pytest.raises(FolderBusy, match="another process"):
            run(tmp_path, job(), workers=0, progress=False)
    assert CALLS == []


def test_workers_default_to_one_per_core_and_are_bounded(tmp_path):
    assert default_workers() == len(os.sched_getaffinity(0))
    with pytest.raises(SpecError, match=r"--workers must be an integer in \[0, 64\] \(0: in this process"):
        run(tmp_path, job(), workers=1000, progress=False)


def _where(task, payload, sink):
    return {"pid": os.getpid(), "first": task.first}


@pytest.mark.parametrize("workers", [1, pytest.param(2, marks=pytest.mark.slow(
    cover="tests/pipeline/test_runner.py::test_a_job_of_one_shard_runs_in_this_process_and_more_shards_in_workers"))])
def test_a_job_of_one_shard_runs_in_this_process_and_more_shards_in_workers(tmp_path, workers):
    """One shard occupies one core wherever it runs: no cluster is started for it (its
    start-up costs more CPU than a small job's work); two shards go to worker processes.
    The rule does not depend on the worker count: workers=2 repeats workers=1's check with
    a second worker process to start (2.8 CPU s), under -m slow."""
    for ranges, here in (([(0, 4)], True), ([(0, 2), (2, 4)], False)):
        seen: list[dict] = []
        task_module.run_tasks([ShardTask("linear-fast", a, b) for a, b in ranges], _where, None,
                              ShardSink(str(tmp_path)), Execution(workers), seen.append)
        assert sorted(r["first"] for r in seen) == [a for a, _ in ranges]
        assert all((r["pid"] == os.getpid()) == here for r in seen), (ranges, seen)


def test_a_scheduler_address_that_is_not_a_scheduler_is_one_error(monkeypatch):
    """Something listening that never speaks Dask (here a silent socket on 127.0.0.1) is
    refused after the connect timeout instead of hanging the build."""
    import socket

    from dask.distributed import Client

    from schemas.errors import DyanaError

    monkeypatch.setattr(task_module, "CONNECT_TIMEOUT_S", 0.2)
    monkeypatch.setattr(task_module, "CONNECT_GRACE_S", 0.3)
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        with pytest.raises(DyanaError, match=r"cannot connect to the Dask scheduler: no Dask handshake within 0.2 s"):
            task_module.connect(Client, address)


# --- progress ------------------------------------------------------------------------------


def spec_shard(task: ShardTask, payload: str, sink: ShardSink) -> dict:
    """A fake shard that walks its specs the way build and eval do."""
    for _spec in task.specs():
        pass
    return fake_shard(task, payload, sink)


def test_progress_is_per_episode_in_process(tmp_path, capsys):
    tasks = tuple(ShardTask("linear-fast", a, b) for a, b in shard_ranges(6, 3))
    spec_job = Job("linear-fast", 1, {"resolution": 32}, {}, tasks, spec_shard, "a", with_stats=False)
    run(tmp_path, spec_job, workers=0, progress=True)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("[0/2 shards] 1/6 episodes, ") and "eta ?" in lines[0]
    assert lines[-1].startswith("[2/2 shards] 6/6 episodes, ") and lines[-1].endswith("eta 0s")
    assert len(lines) == 2  # the rest came within 2 s of the first


def test_specs_report_only_to_the_tasks_reporter():
    heard = []
    task = ShardTask("linear-fast", 4, 7)
    assert [s.episode_index for s in task.specs()] == [4, 5, 6] and heard == []
    specs = task.reporting_to(lambda *report: heard.append(report)).specs()
    assert task.reporting_to(print) == task  # the reporter is not part of what the task is
    for spec in specs:
        assert len(heard) == spec.episode_index - 4  # the previous episode is reported done
    frames = list(itertools.accumulate(s.num_frames for s in task.specs()))
    assert heard == [(4, 7, k + 1, frames[k]) for k in range(3)]


def test_the_meter_prints_at_most_every_interval_and_the_last():
    import io

    from schemas.cli import ProgressMeter

    now = [0.0]
    out = io.StringIO()
    meter = ProgressMeter(10, stream=out, clock=lambda: now[0])
    for done in range(1, 11):
        now[0] = 0.5 * done
        meter.update(done, 20 * done)
    lines = out.getvalue().splitlines()
    # 0.5 s (the first), 2.5 s, 4.5 s, then 5.0 s (the last)
    assert [line.split(" episodes")[0] for line in lines] == ["1/10", "5/10", "9/10", "10/10"]
    assert lines[0] == "1/10 episodes, 20 frames, 40.0 frames/s, eta ?"
    assert lines[1].endswith("eta 2s")  # 4 episodes in 2 s since the first: 0.5 s each, 5 to go
    meter.finish()
    assert len(out.getvalue().splitlines()) == 4


def _build(out: Path, *flags: str) -> subprocess.CompletedProcess:
    import sys

    command = [str(Path(sys.executable).parent / "pipeline"), "build", "--slice", "linear-fast", "--episodes", "8",
               "--shard-size", "4", "--resolution", "32", "--workers", "1", "--out", str(out), *flags]
    return subprocess.run(command, capture_output=True, text=True, timeout=300)


def test_a_dask_build_reports_episodes_before_its_shard_finishes_and_quiet_is_silent(tmp_path):
    """Every line is Dyana's: no Dask log line (heartbeats, comm closing), and no dashboard
    bound to 8787, so no 'Port 8787 is already in use' warning beside another dashboard."""
    import socket

    with socket.socket() as taken:
        try:
            taken.bind(("127.0.0.1", 8787))
        except OSError:
            pass  # already taken by something else: the point holds either way
        shown = _build(tmp_path / "shown")
    assert shown.returncode == 0, shown.stderr
    about, *lines = shown.stderr.splitlines()
    assert about == "building linear-fast: 8 episodes, 225 frames, 2 shards of 4; Ctrl-C keeps finished shards, " \
                    "the same command resumes", about  # how big the job is, before its first line of progress
    # two shards on one Dask worker (a job of one shard would run in the driver)
    early = [line for line in lines if re.match(r"\[0/2 shards\] [1-3]/8 episodes, \d+ frames, [\d.]+ frames/s, eta ", line)]
    assert early, shown.stderr  # a worker process's episode reached the driver before its shard was done
    assert lines[-1].startswith("[2/2 shards] 8/8 episodes, "), shown.stderr
    assert all(re.match(r"\[[0-2]/2 shards\] [1-8]/8 episodes, ", line) for line in lines), shown.stderr
    quiet = _build(tmp_path / "quiet", "--quiet")
    assert quiet.returncode == 0 and quiet.stderr == ""  # no progress, no Dask log lines
    hashes = [load_manifest(tmp_path / name / "linear-fast").hash for name in ("shown", "quiet")]
    in_process = run_job_build(tmp_path / "in-process").manifest
    assert hashes == [in_process.hash] * 2  # progress changes no byte


def run_job_build(out: Path):
    from pipeline.jobs.build import build_job

    return build_job("linear-fast", out, episodes=8, shard_size=4, resolution=32, workers=0, progress=True)


def test_a_resumed_run_counts_the_kept_shards_as_done(tmp_path, capsys):
    def dies(task, payload, folder):
        if task.first == 3:
            raise KeyboardInterrupt
        return spec_shard(task, payload, folder)

    tasks = tuple(ShardTask("linear-fast", a, b) for a, b in shard_ranges(6, 3))
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path, Job("linear-fast", 1, {"resolution": 32}, {}, tasks, dies, "a", with_stats=False),
                workers=0, progress=False)
    run(tmp_path, Job("linear-fast", 1, {"resolution": 32}, {}, tasks, spec_shard, "a", with_stats=False),
            workers=0, progress=True)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "resuming: 1 of 2 shards already built"
    assert lines[1].startswith("[1/2 shards] 4/6 episodes, ") and lines[1].endswith("eta ?")  # 3 kept + 1 new
    assert lines[-1].startswith("[2/2 shards] 6/6 episodes, 6 frames, ")  # the fake shards' frames: 3 + 3
