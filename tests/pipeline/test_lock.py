"""The folder lock holds across processes: never two holders at once, however the starts
race, and a second job on a folder is refused with one line (FolderBusy)."""

from __future__ import annotations

import multiprocessing
import os
import time
from pathlib import Path

import pytest

from pipeline.jobs.lock import LOCK_FILE, FolderBusy, folder_lock

RACE_S = 1.0
PROCESSES = 4


def _contend(folder: str, seconds: float, results: multiprocessing.Queue) -> None:
    """Acquire the lock as often as possible; while holding it, own a marker file made with
    O_EXCL (it fails if another holder's marker is there) and remove it before releasing."""
    marker = os.path.join(folder, "held")
    held = doubled = 0
    stop = time.monotonic() + seconds
    while time.monotonic() < stop:
        try:
            with folder_lock(Path(folder)):
                try:
                    fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
                except FileExistsError:
                    doubled += 1
                    continue
                held += 1
                os.close(fd)
                os.unlink(marker)
        except FolderBusy:
            pass
    results.put((held, doubled))


def test_racing_processes_never_hold_the_lock_together(tmp_path):
    context = multiprocessing.get_context("spawn")
    results = context.Queue()
    workers = [context.Process(target=_contend, args=(str(tmp_path), RACE_S, results)) for _ in range(PROCESSES)]
    for worker in workers:
        worker.start()
    outcomes = [results.get(timeout=60) for _ in workers]
    for worker in workers:
        worker.join(timeout=30)
    assert sum(doubled for _, doubled in outcomes) == 0, outcomes
    assert sum(held for held, _ in outcomes) > 100, outcomes  # they did contend
    assert (tmp_path / LOCK_FILE).is_file()  # left in place, never unlinked


def test_a_held_lock_refuses_at_once_in_one_line(tmp_path):
    with folder_lock(tmp_path):
        with pytest.raises(FolderBusy) as caught:
            with folder_lock(tmp_path):
                pass
    assert "another process is writing this folder" in str(caught.value) and "\n" not in str(caught.value)
    with folder_lock(tmp_path):  # released: free again
        pass


def _slow_shard(task, payload: str, folder: str) -> dict:
    from tests.pipeline.test_runner import fake_shard

    time.sleep(1.0)
    return fake_shard(task, payload, folder)


def _start(folder: str, barrier, results) -> None:
    from pipeline.jobs.runner import Execution, Job, Storage, run_job
    from pipeline.jobs.tasks import ShardTask

    job = Job("linear-fast", 1, {"resolution": 32}, {}, (ShardTask("linear-fast", 0, 2),), _slow_shard,
              "a", with_stats=False)
    barrier.wait()
    try:
        run_job(job, Execution(0), Storage(folder))
        results.put("ran")
    except FolderBusy as exc:
        results.put(f"busy: {exc}")


def test_two_jobs_started_at_once_on_one_folder_one_runs_the_other_is_busy(tmp_path):
    context = multiprocessing.get_context("spawn")
    barrier, results = context.Barrier(2), context.Queue()
    starts = [context.Process(target=_start, args=(str(tmp_path), barrier, results)) for _ in range(2)]
    for start in starts:
        start.start()
    outcomes = sorted(results.get(timeout=120) for _ in starts)
    for start in starts:
        start.join(timeout=30)
    assert outcomes[1] == "ran" and outcomes[0].startswith("busy: ") and "another process" in outcomes[0], outcomes
    assert (tmp_path / "catalog.json").is_file()
