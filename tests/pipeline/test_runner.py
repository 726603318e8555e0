"""The job runner shared by build and eval: one job per folder, resume, up to date,
the lock, worker defaults. Jobs here write tiny fake shards in this process."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

from catalog.records import shard_paths
from pipeline.jobs import runner
from pipeline.jobs.runner import (
    FolderBusy,
    Job,
    ShardTask,
    default_workers,
    folder_lock,
    run_job,
    shard_ranges,
)
from schemas.errors import SpecError

CALLS: list[int] = []


def fake_shard(task: ShardTask, payload: str, folder: str) -> dict:
    CALLS.append(task.first)
    files = {}
    for kind, rel in shard_paths(task.first, task.end).items():
        data = f"{payload}:{kind}:{task.first}".encode()
        (Path(folder) / rel).write_bytes(data)
        files[kind] = {"path": rel, "sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}
    return {"record": {"episodes": [task.first, task.end], "frames": task.end - task.first, "files": files}}


def job(folder: Path, episodes: int = 4, shard_size: int = 2, payload: str = "a", extra: dict | None = None) -> Job:
    tasks = tuple(ShardTask("linear-fast", a, b) for a, b in shard_ranges(episodes, shard_size))
    return Job(folder, "linear-fast", 1, {"resolution": 32}, extra or {}, tasks, fake_shard, payload, with_stats=False)


@pytest.fixture(autouse=True)
def _calls():
    CALLS.clear()


def test_a_complete_identical_job_is_up_to_date(tmp_path):
    first, fresh = run_job(job(tmp_path), workers=0, progress=False)
    assert not fresh and CALLS == [0, 2]
    CALLS.clear()
    again, up_to_date = run_job(job(tmp_path), workers=0, progress=False)
    assert up_to_date and CALLS == [] and again == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["catalog.json", "shards"]  # no lock or state left


def test_a_damaged_shard_alone_is_redone(tmp_path):
    manifest, _ = run_job(job(tmp_path), workers=0, progress=False)
    (tmp_path / manifest.shards[1].files["mcap"].path).write_bytes(b"tampered")
    CALLS.clear()
    again, up_to_date = run_job(job(tmp_path), workers=0, progress=False)
    assert not up_to_date and CALLS == [2] and again.hash == manifest.hash


@pytest.mark.parametrize(
    "other, named",
    [
        (dict(episodes=2), "episodes 4 -> 2"),
        (dict(shard_size=1), "shards"),
        (dict(extra={"policy": "chase"}), 'extra.policy null -> "chase"'),
    ],
)
def test_another_job_is_refused_naming_the_difference_and_nothing_is_lost(tmp_path, other, named):
    manifest, _ = run_job(job(tmp_path), workers=0, progress=False)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    with pytest.raises(SpecError, match="another job") as caught:
        run_job(job(tmp_path, **other), workers=0, progress=False)
    assert named in str(caught.value) and "--overwrite" in str(caught.value)
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before
    replaced, _ = run_job(job(tmp_path, **other), workers=0, progress=False, overwrite=True)
    listed = {f.path for s in replaced.shards for f in s.files.values()}
    assert {str(p.relative_to(tmp_path)) for p in (tmp_path / "shards").iterdir()} == listed


def test_an_interrupted_run_of_another_job_is_refused(tmp_path, monkeypatch):
    def dies(task, payload, folder):
        if task.first == 2:
            raise KeyboardInterrupt
        return fake_shard(task, payload, folder)

    with pytest.raises(KeyboardInterrupt):
        run_job(Job(tmp_path, "linear-fast", 1, {"resolution": 32}, {}, job(tmp_path).tasks, dies, "a", with_stats=False),
                workers=0, progress=False)
    assert (tmp_path / runner.STATE_FILE).exists() and not (tmp_path / "catalog.json").exists()
    with pytest.raises(SpecError, match="unfinished run of another job"):
        run_job(job(tmp_path, episodes=2), workers=0, progress=False)
    CALLS.clear()
    run_job(job(tmp_path), workers=0, progress=False)
    assert CALLS == [2]  # the same job resumes


def test_a_second_process_on_the_folder_is_refused(tmp_path):
    with folder_lock(tmp_path):
        with pytest.raises(FolderBusy, match="another process"):
            run_job(job(tmp_path), workers=0, progress=False)
    assert CALLS == []


def test_workers_default_to_one_per_core_and_are_bounded(tmp_path):
    assert default_workers() == len(os.sched_getaffinity(0))
    with pytest.raises(SpecError, match="--workers"):
        run_job(job(tmp_path), workers=1000, progress=False)


def test_a_scheduler_address_that_is_not_a_scheduler_is_one_error(monkeypatch):
    """Something listening that never speaks Dask (here a silent socket on 127.0.0.1) is
    refused after the connect timeout instead of hanging the build."""
    import socket

    from dask.distributed import Client

    from schemas.errors import DyanaError

    monkeypatch.setattr(runner, "CONNECT_TIMEOUT_S", 1.0)
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        with pytest.raises(DyanaError, match=r"cannot connect to the Dask scheduler: no Dask handshake within 1 s"):
            runner._connect(Client, address)
