"""One driver for sharded jobs: `pipeline build`, `pipeline eval` and anything after them.

A :class:`Job` names an output folder, what it will hold (slice, seed, settings, extra
manifest keys such as a specs file's hash, shard ranges) and a worker function that writes one
shard. :func:`run_job` owns everything around the shards:

- the folder holds one job: a ``catalog.json`` (or a killed run's ``.build-state.json``)
  describing anything else is refused with a message naming what differs, unless
  ``overwrite``; a second process on the folder is refused by a lock;
- stray temporaries of dead processes are removed; finished shards of an interrupted
  run of the same job (same code commit) whose files still match their sha256 are kept,
  so a killed run resumes, and a complete identical folder is reported up to date;
- the shards run as Dask tasks (a local cluster of single-threaded worker processes,
  one per core by default, or an existing ``--scheduler``), or in this process with
  ``workers=0``;
- progress lines go to stderr per finished episode, at most one per 2 s plus the last
  (:class:`schemas.cli.ProgressMeter`): a shard task iterates :meth:`ShardTask.specs`,
  which reports an episode finished when the task asks for the next one (and the shard's
  record completes the count); a Dask worker sends the report as a Dask event
  (``Worker.log_event``) on a topic of this run that the driver's client subscribes to.
  Reports carry only counts, go to the terminal alone and never reach a file;
- ``stats.json`` (normalisation statistics of states and actions) is computed from the
  finished shards, then ``catalog.json`` is written last (one way,
  :meth:`catalog.manifest.Manifest.create`), then files of a replaced job are removed.

The manifest's hash covers the slice, seed, settings, statistics and the ordered file
hashes, so the worker count, the scheduler and interruptions cannot change it.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import sys
import threading
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from catalog.atomic import atomic_write_text, remove_stray_temps
from catalog.manifest import (
    CodeInfo,
    Manifest,
    git_commit,
    load_manifest,
    manifest_path,
    write_manifest,
)
from catalog.reader import check_file
from catalog.records import FileRecord, ShardRecord, shard_like_files
from catalog.stats import compute_stats, write_stats
from schemas.cli import ProgressMeter
from schemas.errors import DyanaError, ShardError, SpecError
from schemas.names import shorten
from schemas.spec import EpisodeSpec
from schemas.versions import CODE_VERSION

STATE_FILE = ".build-state.json"
LOCK_FILE = ".lock"
#: The most local worker processes a run starts (each holds a simulator and a renderer).
MAX_WORKERS = 64

#: Worker settings for CPU-bound whole-shard tasks: no statistical profiler sampling the
#: task thread every 10 ms, no work stealing of long tasks, no spilling (results are tiny).
LEAN_WORKERS = {
    "distributed.worker.profile.enabled": False,
    "distributed.scheduler.work-stealing": False,
    "distributed.worker.memory.spill": False,
    "distributed.worker.memory.target": False,
}


def default_workers() -> int:
    """One worker per core this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


#: ``(first, end, done, frames)``: ``done`` episodes (``frames`` frames) of the shard
#: [first, end) are finished.
EpisodeReport = Callable[[int, int, int, int], None]

#: Where a running shard task reports its finished episodes (set around the task).
_reporter: EpisodeReport | None = None


@contextlib.contextmanager
def reporting_episodes(report: EpisodeReport | None) -> Iterator[None]:
    """Within the block, iterating :class:`ReportingSpecs` calls ``report``."""
    global _reporter
    previous, _reporter = _reporter, report
    try:
        yield
    finally:
        _reporter = previous


class ReportingSpecs(list[EpisodeSpec]):
    """A shard's specs (a plain list of EpisodeSpec); iterating it inside
    :func:`reporting_episodes` reports each episode finished when the next is asked for
    (its frames counted as the spec's ``num_frames``). Outside, it is just the list."""

    def __init__(self, specs: Sequence[EpisodeSpec], first: int, end: int) -> None:
        super().__init__(specs)
        self.first, self.end = first, end

    def __iter__(self) -> Iterator[EpisodeSpec]:
        report = _reporter
        if report is None:
            return super().__iter__()
        return self._reporting(report)

    def _reporting(self, report: EpisodeReport) -> Iterator[EpisodeSpec]:
        done = frames = 0
        for spec in super().__iter__():
            yield spec
            done += 1
            frames += int(spec.num_frames)
            with contextlib.suppress(Exception):  # progress never fails a shard
                report(self.first, self.end, done, frames)


@dataclass(frozen=True)
class ShardTask:
    """One shard: episodes [first, end) of ``slice_name``, from the recipe or from given specs."""

    slice_name: str
    first: int
    end: int
    specs_json: tuple[str, ...] | None = None

    def specs(self) -> list[EpisodeSpec]:
        """The shard's specs, as a :class:`ReportingSpecs` (episode progress)."""
        if self.specs_json is not None:
            return ReportingSpecs([EpisodeSpec.from_json(text) for text in self.specs_json], self.first, self.end)
        from generators.recipe import spec_for

        return ReportingSpecs([spec_for(self.slice_name, i) for i in range(self.first, self.end)], self.first, self.end)


def shard_ranges(episodes: int, shard_size: int) -> list[tuple[int, int]]:
    """Fixed episode ranges [first, end) of at most ``shard_size`` episodes."""
    if isinstance(shard_size, bool) or not isinstance(shard_size, int) or shard_size < 1:
        raise SpecError(f"--shard-size must be an integer >= 1, got {shard_size!r}")
    return [(a, min(a + shard_size, episodes)) for a in range(0, episodes, shard_size)]


@dataclass(frozen=True)
class Job:
    """A sharded job. ``task_fn(task, payload, folder)`` runs in a worker and returns a
    dict with the shard's ``record`` (a ShardRecord dict) and anything else the caller's
    ``on_result`` wants (timing). ``extra`` are the manifest's top-level keys beyond the
    contract's; with ``settings``, ``slice``, ``seed`` and the shard ranges they say what
    the folder holds."""

    folder: Path
    slice_name: str
    seed: int | None
    settings: Mapping[str, Any]
    extra: Mapping[str, Any]
    tasks: tuple[ShardTask, ...]
    task_fn: Callable[[ShardTask, Any, str], dict]
    payload: Any
    verb: str = "built"
    key_prefix: str = "shard"
    with_stats: bool = True
    ranges: tuple[tuple[int, int], ...] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ranges", tuple((t.first, t.end) for t in self.tasks))

    @property
    def episodes(self) -> int:
        return self.ranges[-1][1] if self.ranges else 0

    def identity(self) -> dict[str, Any]:
        """What the folder must already hold for this job to reuse it."""
        return {
            "slice": self.slice_name,
            "seed": self.seed,
            "episodes": self.episodes,
            "shards": [list(r) for r in self.ranges],
            "settings": dict(self.settings),
            **{f"extra.{k}": v for k, v in sorted(self.extra.items())},
        }


def _manifest_identity(manifest: Manifest) -> dict[str, Any]:
    return {
        "slice": manifest.slice,
        "seed": manifest.seed,
        "episodes": manifest.episodes,
        "shards": [list(s.episodes) for s in manifest.shards],
        "settings": dict(manifest.settings),
        **{f"extra.{k}": v for k, v in sorted(manifest.extra.items())},
    }


def _short(value: Any, limit: int = 80) -> str:
    text = json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def describe_difference(held: Mapping[str, Any], wanted: Mapping[str, Any]) -> str:
    """The first few keys on which two identities differ, as ``key held -> wanted``."""
    keys = [k for k in sorted(set(held) | set(wanted)) if held.get(k) != wanted.get(k)]
    if "shards" in keys and "episodes" in keys:
        keys.remove("shards")
    parts = [f"{k} {_short(held.get(k))} -> {_short(wanted.get(k))}" for k in keys[:3]]
    if len(keys) > 3:
        parts.append(f"and {len(keys) - 3} more")
    return "; ".join(parts)


class FolderBusy(DyanaError):
    """Another process holds the folder's lock."""


@contextlib.contextmanager
def folder_lock(folder: Path) -> Iterator[None]:
    """Hold ``folder/.lock`` for the duration: one job per folder at a time.

    The lock is the kernel's (``flock``), so a killed holder releases it; the file is
    removed while still held, leaving nothing behind after a finished run."""
    path = folder / LOCK_FILE
    handle = open(path, "a+")
    held = False
    try:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FolderBusy(f"{folder}: another process is writing this folder (lock {path} is held)") from None
        held = True
        yield
    finally:
        if held:
            path.unlink(missing_ok=True)
        handle.close()


def _file_intact(folder: Path, record: FileRecord) -> bool:
    try:
        check_file(folder, record, "sha256")
    except ShardError:
        return False
    return True


def _intact(folder: Path, record: ShardRecord) -> bool:
    return all(_file_intact(folder, f) for f in record.files.values())


def _previous_work(job: Job, commit: str | None, overwrite: bool) -> tuple[dict[tuple[int, int], ShardRecord], bool]:
    """Finished shards this job may keep, and whether the folder is already complete.

    Refuses (SpecError) a folder holding another job unless ``overwrite``."""
    folder, wanted = job.folder, job.identity()
    state_path = folder / STATE_FILE
    held: dict[str, Any] | None = None
    records: list[ShardRecord] = []
    code: tuple[str | None, str | None] = (None, None)
    complete = False
    if manifest_path(folder).exists():
        try:
            manifest = load_manifest(folder)
        except ShardError:
            if not overwrite:
                raise
        else:
            held, records = _manifest_identity(manifest), list(manifest.shards)
            complete = _file_intact(folder, manifest.stats) if manifest.stats is not None else not job.with_stats
            code = (manifest.code.version, manifest.code.commit)
    if held is None and state_path.exists():
        try:
            state = json.loads(state_path.read_text())
            held = state["identity"]
            records = [ShardRecord.from_dict(raw) for raw in state["shards"]]
            code = (state["code"]["version"], state["code"]["commit"])
        except (OSError, ValueError, KeyError, TypeError, ShardError) as exc:
            if not overwrite:
                raise ShardError(
                    f"{state_path}: unreadable state of an interrupted run ({type(exc).__name__}); "
                    "pass --overwrite to start the folder afresh"
                ) from None
            held = None
    if held is None:
        return {}, False
    if held != wanted:
        if overwrite:
            manifest_path(folder).unlink(missing_ok=True)
            state_path.unlink(missing_ok=True)
            return {}, False
        what = "holds" if complete else "holds an unfinished run of"
        raise SpecError(
            f"{folder} {what} another job ({describe_difference(held, wanted)}): "
            "choose another --out, or pass --overwrite to replace it"
        )
    if code != (CODE_VERSION, commit):
        return {}, False
    done = {(r.first, r.end): r for r in records if _intact(folder, r)}
    return done, complete and len(done) == len(records)


def _save_state(job: Job, commit: str | None, done: Mapping[tuple[int, int], ShardRecord]) -> None:
    state = {
        "identity": job.identity(),
        "code": {"version": CODE_VERSION, "commit": commit},
        "shards": [done[key].to_dict() for key in sorted(done)],
    }
    atomic_write_text(job.folder / STATE_FILE, json.dumps(state, sort_keys=True, indent=2) + "\n")


class Progress:
    """The driver's progress lines: episodes done (per episode, as workers report them, and
    per finished shard), frames, frames/s and ETA, with the shards finished in front; the
    last line when every shard is finished. Frames of unfinished shards are counted from
    their specs' lengths (a rollout that ends early has fewer: its shard's record corrects
    the count)."""

    def __init__(self, total_shards: int, total_episodes: int, stream=None) -> None:
        self.total_shards = total_shards
        self.meter = ProgressMeter(total_episodes, "episodes", stream=stream)
        self._lock = threading.Lock()
        self._running: dict[tuple[int, int], tuple[int, int]] = {}
        self._finished: dict[tuple[int, int], tuple[int, int]] = {}

    def _show(self) -> None:
        parts = [*self._running.values(), *self._finished.values()]
        self.meter.update(
            sum(p[0] for p in parts),
            sum(p[1] for p in parts),
            prefix=f"[{len(self._finished)}/{self.total_shards} shards]",
            last=len(self._finished) == self.total_shards,
        )

    def resumed(self, records: Sequence[ShardRecord]) -> None:
        """Shards finished before this run: done, but not part of the rates."""
        with self._lock:
            for record in records:
                self._finished[(record.first, record.end)] = (record.end - record.first, record.frames)
            self.meter.resume(sum(p[0] for p in self._finished.values()), sum(p[1] for p in self._finished.values()))

    def episode(self, first: int, end: int, done: int, frames: int) -> None:
        """A worker's report: ``done`` episodes of shard [first, end) are finished."""
        with self._lock:
            key = (first, end)
            if key in self._finished or done <= self._running.get(key, (0, 0))[0]:
                return  # late or repeated
            self._running[key] = (done, frames)
            self._show()

    def update(self, record: ShardRecord) -> None:
        """A shard finished: its episodes and (recorded) frames."""
        with self._lock:
            key = (record.first, record.end)
            self._running.pop(key, None)
            self._finished[key] = (record.end - record.first, record.frames)
            self._show()


def check_workers(workers: int, scheduler: str | None) -> None:
    if scheduler:
        return
    if isinstance(workers, bool) or not isinstance(workers, int) or not 0 <= workers <= MAX_WORKERS:
        raise SpecError(f"--workers must be an integer in [1, {MAX_WORKERS}], got {workers!r}")


@contextlib.contextmanager
def _quiet_dask() -> Iterator[None]:
    """Keep Dask's own log lines (a task's traceback, shutdown chatter) out of the
    driver's output: a failure reaches the user once, as Dyana's one-line error."""
    logger = logging.getLogger("distributed")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


#: Seconds a --scheduler has to answer as a Dask scheduler.
CONNECT_TIMEOUT_S = 30.0


def _connect(client_class: Any, scheduler: str) -> Any:
    """A Client of ``scheduler``, or one DyanaError: unreachable, not an address, or
    something that is not a Dask scheduler (which may never answer the handshake, hence
    the connection runs on a thread we stop waiting for)."""
    outcome: dict[str, Any] = {}

    def attempt() -> None:
        try:
            outcome["client"] = client_class(scheduler, timeout=f"{CONNECT_TIMEOUT_S:g}s")
        except BaseException as exc:  # reported below, in the caller's thread
            outcome["error"] = exc

    thread = threading.Thread(target=attempt, name="dyana-dask-connect", daemon=True)
    thread.start()
    thread.join(CONNECT_TIMEOUT_S + 5.0)
    where = f"--scheduler {shorten(scheduler)!r}: cannot connect to the Dask scheduler"
    if "client" in outcome:
        return outcome["client"]
    error = outcome.get("error")
    if error is None:
        raise DyanaError(f"{where}: no Dask handshake within {CONNECT_TIMEOUT_S:g} s (is it a Dask scheduler?)")
    if isinstance(error, MemoryError):
        raise DyanaError(f"{where}: it did not answer as a Dask scheduler") from None
    if isinstance(error, (OSError, ValueError, TypeError)):
        raise DyanaError(f"{where}: {shorten(str(error), 200)}") from None
    raise error


def run_tasks(
    tasks: Sequence[ShardTask],
    task_fn: Callable[[ShardTask, Any, str], dict],
    payload: Any,
    folder: Path,
    workers: int,
    scheduler: str | None,
    on_done: Callable[[dict], None],
    key_prefix: str = "shard",
    on_episode: EpisodeReport | None = None,
) -> None:
    """Run ``task_fn(task, payload, str(folder))`` for every task on a local cluster (one
    single-threaded process per worker), on an existing scheduler, or in this process
    (``workers == 0``); call ``on_done`` in the driver with each result as it finishes, and
    ``on_episode`` (on another thread with Dask) with the tasks' episode reports."""
    if not tasks:
        return
    if workers == 0 and not scheduler:
        with reporting_episodes(on_episode):
            for task in tasks:
                on_done(task_fn(task, payload, str(folder)))
        return
    import dask
    from dask.distributed import Client, LocalCluster, as_completed

    with dask.config.set(LEAN_WORKERS), _quiet_dask():
        cluster = None
        if scheduler:
            client = _connect(Client, scheduler)
        else:
            cluster = LocalCluster(
                n_workers=min(workers, len(tasks)),
                threads_per_worker=1,
                processes=True,
                dashboard_address="127.0.0.1:0",  # None still starts one on 8787 (dask/distributed#8136)
                silence_logs=logging.CRITICAL,
            )
            try:
                client = Client(cluster)
            except BaseException:
                cluster.close()
                raise
        listening = on_episode is not None
        topic = f"dyana-progress-{uuid.uuid4().hex}"  # this run's alone, on a shared scheduler too

        def heard(event: tuple[float, Any]) -> None:  # on the client's event loop thread
            if listening and on_episode is not None:
                with contextlib.suppress(Exception):
                    msg = event[1]
                    on_episode(int(msg["first"]), int(msg["end"]), int(msg["done"]), int(msg["frames"]))

        try:
            if on_episode is not None:
                client.subscribe_topic(topic, heard)
            futures = [
                client.submit(
                    _reporting_task,
                    task_fn,
                    task,
                    payload,
                    str(folder),
                    topic if on_episode is not None else None,
                    key=f"{key_prefix}-{task.first:06d}-{task.end:06d}",
                    pure=False,
                )
                for task in tasks
            ]
            for future in as_completed(futures):
                on_done(future.result())
        finally:
            listening = False
            client.close()
            if cluster is not None:
                cluster.close()


def _reporting_task(
    task_fn: Callable[[ShardTask, Any, str], dict], task: ShardTask, payload: Any, folder: str, topic: str | None
) -> dict:
    """Worker side: ``task_fn``, its episode reports sent to the driver as Dask events on ``topic``."""
    if topic is None:
        return task_fn(task, payload, folder)
    from distributed import get_worker

    worker = get_worker()

    def report(first: int, end: int, done: int, frames: int) -> None:
        worker.log_event(topic, {"first": first, "end": end, "done": done, "frames": frames})

    with reporting_episodes(report):
        return task_fn(task, payload, folder)


def remove_unlisted_shards(folder: Path, manifest: Manifest) -> list[Path]:
    """Delete shard files that ``manifest`` does not list: what is left of a job this one
    replaced (``--overwrite``), which would otherwise fail ``catalog verify`` and be read
    by anything opening ``frames/`` as a dataset. Only files named like shards, in the
    shard folders, are touched."""
    listed = {path for path, _, _ in manifest.files()}
    removed = []
    for path in shard_like_files(folder):
        if path.relative_to(folder).as_posix() not in listed:
            path.unlink()
            removed.append(path)
    return removed


def run_job(
    job: Job,
    *,
    workers: int,
    scheduler: str | None = None,
    progress: bool = True,
    overwrite: bool = False,
    on_result: Callable[[dict], None] | None = None,
) -> tuple[Manifest, bool]:
    """Run ``job`` into its folder; the manifest, and whether the folder was already up to date."""
    check_workers(workers, scheduler)
    folder = job.folder
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SpecError(f"{folder}: cannot create the output folder ({exc.strerror or exc})") from None
    with folder_lock(folder):
        remove_stray_temps(folder)
        commit = git_commit()
        done, complete = _previous_work(job, commit, overwrite)
        if complete:
            return load_manifest(folder), True
        done = {key: record for key, record in done.items() if key in set(job.ranges)}
        todo = [task for task in job.tasks if (task.first, task.end) not in done]

        meter = Progress(len(job.ranges), job.episodes) if progress else None
        if meter is not None and done:
            print(f"resuming: {len(done)} of {len(job.ranges)} shards already {job.verb}", file=sys.stderr)
            meter.resumed([done[key] for key in sorted(done)])

        def on_done(result: dict) -> None:
            record = ShardRecord.from_dict(result["record"])
            done[(record.first, record.end)] = record
            _save_state(job, commit, done)
            if on_result is not None:
                on_result(result)
            if meter is not None:
                meter.update(record)

        try:
            run_tasks(
                todo,
                job.task_fn,
                job.payload,
                folder,
                workers,
                scheduler,
                on_done,
                job.key_prefix,
                on_episode=meter.episode if meter is not None else None,
            )
        finally:
            remove_stray_temps(folder)  # what workers that died (killed, out of memory) left behind

        shards = [done[key] for key in job.ranges]
        stats = write_stats(folder, compute_stats(folder, shards)) if job.with_stats else None
        manifest = Manifest.create(
            job.slice_name,
            job.seed,
            job.settings,
            shards,
            code=CodeInfo(CODE_VERSION, commit),
            extra=job.extra,
            stats=stats,
        )
        write_manifest(folder, manifest)
        remove_unlisted_shards(folder, manifest)
        (folder / STATE_FILE).unlink(missing_ok=True)
    return manifest, False
