"""Shard tasks and where they run: a local Dask cluster of single-threaded worker processes
(one per core by default, at most one per task), an existing ``--scheduler``, or this
process (``workers=0``, or a job of one task without a scheduler).

A task is ``task_fn(task, payload, sink)``; it writes its shard files through ``sink``
(:class:`pipeline.jobs.sink.ShardSink`: the job's output folder or URL, which a worker on
any host can open) and returns a plain dict with the shard's ``record`` and whatever else
its job's caller wants (timing). Its episode reports reach the driver through
:attr:`ShardTask.report`: in this process the driver's own callback, in a Dask worker a
function sending a Dask event (``Worker.log_event``) on a topic of this run that the
driver's client subscribes to.

Ctrl-C is the driver's: local workers start with SIGINT blocked and then ignore it
(:func:`sigint_held`, :func:`dask_setup`), the driver closes the cluster, and a lost
scheduler or a task whose every worker died is one :class:`~schemas.errors.DyanaError`
(:func:`dask_failure`), not Dask's tracebacks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import multiprocessing
import os
import re
import signal
import threading
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import CancelledError
from dataclasses import dataclass, field
from multiprocessing import resource_tracker
from pathlib import Path
from typing import Any, Generic, TypeVar

from catalog.tables.partial import PartialShard
from pipeline.jobs.progress import EpisodeReport, ReportingSpecs, to_stderr
from pipeline.jobs.sink import ShardSink
from schemas.errors import DyanaError, SpecError
from schemas.names import shorten
from schemas.spec import EpisodeSpec

#: The most local worker processes a run starts (each holds a simulator and a renderer).
MAX_WORKERS = 64
#: Seconds a --scheduler has to answer as a Dask scheduler.
CONNECT_TIMEOUT_S = 30.0
#: Seconds more the driver waits for the connecting thread: Dask's own timeout does not end
#: a handshake that a silent peer never answers, so the driver stops waiting instead.
CONNECT_GRACE_S = 5.0

#: Worker settings for CPU-bound whole-shard tasks: no statistical profiler sampling the
#: task thread every 10 ms, no work stealing of long tasks, no spilling (results are tiny);
#: worker processes forked from a server that has imported Dask and numpy once (Dask's own
#: test suite does so), not each started afresh, where the platform has one: a two-worker
#: build of 4 episodes took 6.7 CPU s instead of 8.2, the same bytes.
LEAN_WORKERS = {
    "distributed.worker.profile.enabled": False,
    "distributed.scheduler.work-stealing": False,
    "distributed.worker.memory.spill": False,
    "distributed.worker.memory.target": False,
    "distributed.worker.multiprocessing-method": (
        "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"),
}

Payload = TypeVar("Payload")


def default_workers() -> int:
    """One worker per core this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


#: A Dask scheduler address: ``[PROTOCOL://]HOST:PORT`` for tcp and tls (Dask's default
#: protocol is tcp), ``PROTOCOL://ADDRESS`` for the others (inproc, ucx, ...).
_SCHEDULER = re.compile(r"(?:(?:tcp|tls)://)?(?:\[[0-9A-Fa-f:.]+\]|[^\s:/\[\]]+):(\d{1,5})|(?!(?:tcp|tls)://)[a-z][a-z0-9+.-]*://\S+")


def check_scheduler(scheduler: str | None) -> None:
    """SpecError unless ``scheduler`` is None or a Dask scheduler address (a port 1..65535 for
    tcp and tls), so that a malformed one is refused before the output folder is made."""
    if scheduler is None:
        return
    match = _SCHEDULER.fullmatch(scheduler) if isinstance(scheduler, str) else None
    if match is None or (match.group(1) is not None and not 1 <= int(match.group(1)) <= 65535):
        shown = shorten(scheduler) if isinstance(scheduler, str) else scheduler
        raise SpecError(f"--scheduler {shown!r}: not a Dask scheduler address (expected e.g. tcp://127.0.0.1:8786)")


def check_workers(workers: int, scheduler: str | None) -> None:
    """SpecError unless ``workers`` is 0 (this process) to :data:`MAX_WORKERS` (ignored with a
    scheduler, whose address :func:`check_scheduler` checks)."""
    check_scheduler(scheduler)
    if scheduler:
        return
    if isinstance(workers, bool) or not isinstance(workers, int) or not 0 <= workers <= MAX_WORKERS:
        raise SpecError(
            f"--workers must be an integer in [0, {MAX_WORKERS}] (0: in this process, without Dask), got {shorten(repr(workers))}"
        )


@dataclass(frozen=True)
class ShardTask:
    """One shard: episodes [first, end) of ``slice_name``, from the recipe or from given
    specs; ``report`` is where it reports finished episodes (set by the runner);
    ``staging`` is the job key its finished episodes are staged under while it runs
    (:mod:`catalog.tables.partial`; set by the engine, None: not staged)."""

    slice_name: str
    first: int
    end: int
    specs_json: tuple[str, ...] | None = None
    report: EpisodeReport | None = field(default=None, compare=False, repr=False)
    staging: str | None = field(default=None, compare=False, repr=False)

    def specs(self) -> list[EpisodeSpec]:
        """The shard's specs, as :class:`ReportingSpecs` (episode progress to :attr:`report`)."""
        if self.specs_json is not None:
            specs = [EpisodeSpec.from_json(text) for text in self.specs_json]
        else:
            from generators.recipe import spec_for  # the recipe is loaded only by tasks that draw from it

            specs = [spec_for(self.slice_name, i) for i in range(self.first, self.end)]
        return ReportingSpecs(specs, self.first, self.end, self.report)

    def reporting_to(self, report: EpisodeReport | None) -> ShardTask:
        """This task, reporting its episodes to ``report``."""
        return dataclasses.replace(self, report=report)

    def partial(self, folder: Path) -> PartialShard | None:
        """Where this shard's finished episodes are staged in the output ``folder`` the task
        writes; None when they are not (the engine stages only a local folder's tasks, not
        a sample rebuilt in a scratch folder or an object store's upload)."""
        return None if self.staging is None else PartialShard(folder, self.first, self.end, self.staging)


def shard_ranges(episodes: int, shard_size: int) -> list[tuple[int, int]]:
    """Fixed episode ranges [first, end) of at most ``shard_size`` episodes."""
    if isinstance(shard_size, bool) or not isinstance(shard_size, int) or shard_size < 1:
        raise SpecError(f"--shard-size must be an integer >= 1, got {shorten(repr(shard_size))}")
    return [(a, min(a + shard_size, episodes)) for a in range(0, episodes, shard_size)]


TaskFn = Callable[[ShardTask, Payload, ShardSink], dict[str, Any]]

#: The key of a task result counting the episodes it took from its shard's staging folder
#: (an interrupted run's, :mod:`catalog.tables.partial`) instead of computing them.
STAGED_EPISODES = "staged_episodes"


@contextlib.contextmanager
def quiet_dask() -> Iterator[None]:
    """Keep Dask's own log lines (a task's traceback, a lost scheduler's, shutdown chatter)
    out of the driver's output: a failure reaches the user once, as Dyana's one-line error.
    Dask sets the level of some of its loggers (``distributed.client``), so each is quieted."""
    names = ["distributed", *(name for name in logging.root.manager.loggerDict if name.startswith("distributed."))]
    loggers = [logging.getLogger(name) for name in names]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


def preload_in_forkserver(task_fn: Callable[..., Any]) -> None:
    """Have the local workers' forkserver import the task's module (and this one) once,
    before it forks them, beside what Dask has it import (Dask, numpy): each worker then
    starts with them instead of importing them again. Dask picks its workers' context with
    :func:`distributed.utils.get_mp_context`, which sets the forkserver's list the first
    time; this sets it again, Dask's packages first, through multiprocessing's public
    ``set_forkserver_preload``. Without a forkserver, or once it has started (a second
    cluster in this process), nothing changes."""
    from distributed.utils import get_mp_context
    from distributed.versions import optional_packages, required_packages

    context = get_mp_context()
    if context.get_start_method() != "forkserver":
        return
    wanted = ["distributed", *required_packages, *optional_packages, __name__, task_fn.__module__]
    # "__main__" would have the server run the driver's script again (multiprocessing's rule)
    context.set_forkserver_preload([name for name in dict.fromkeys(wanted) if name != "__main__"])


def dask_setup(worker: object) -> None:
    """Dask's preload hook, run in each local worker process as it starts: Ctrl-C (SIGINT to
    the terminal's whole process group) is the driver's to handle, by closing the cluster;
    a worker that took it would print its own KeyboardInterrupt traceback. The worker was
    started with SIGINT blocked (:func:`sigint_held`); ignoring it drops one pending since."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@contextlib.contextmanager
def sigint_held() -> Iterator[None]:
    """SIGINT blocked in this (main) thread for the block: the threads and processes started
    meanwhile (Dask's event loop, the local workers) inherit it blocked, so a Ctrl-C while a
    cluster starts reaches no worker, and takes effect in the driver when the block ends."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    resource_tracker.ensure_running()  # now: starting it later would unblock SIGINT in the thread that does
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """SIGINT ignored for the block (in the main thread): a second Ctrl-C does not cut
    short the closing of a cluster after the first."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def dask_failure(exc: BaseException, scheduler: str | None) -> DyanaError | None:
    """Dask's own failures as one DyanaError: the scheduler lost, or a task whose every worker
    died (a crash in native code, a kill for memory); None for any other exception."""
    from distributed import KilledWorker  # loaded: only runs that use Dask get here
    from distributed.comm.core import CommClosedError

    where = f"--scheduler {shorten(scheduler)!r}" if scheduler else "the local Dask cluster"
    if isinstance(exc, (CancelledError, CommClosedError)):
        return DyanaError(f"{where}: lost the connection to the Dask scheduler; the shards finished so far are "
                          "kept: rerun the same command to resume")
    if isinstance(exc, KilledWorker):
        return DyanaError(f"task {shorten(str(exc.task))!r}: each Dask worker that ran it died "
                          f"({exc.allowed_failures + 1} tries: killed, out of memory or a crash in native code); "
                          "rerun the same command to resume")
    return None


def connect(client_class: Callable[..., Any], scheduler: str) -> Any:
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
    thread.join(CONNECT_TIMEOUT_S + CONNECT_GRACE_S)
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


@dataclass(frozen=True)
class Work(Generic[Payload]):
    """A job's units: its ``tasks``, the worker function that runs one
    (``task_fn(task, payload, sink)``), the ``payload`` sent with each, the prefix of their
    Dask keys, the verb progress lines use (``built``, ``evaluated``, ``exported``),
    ``about``: how big the job is, said before its first unit starts (not when the folder is
    already up to date), and ``staging``: a digest of the job's identity when its tasks stage
    their finished episodes in the output folder (:mod:`catalog.tables.partial`; None: they
    do not)."""

    tasks: tuple[ShardTask, ...]
    task_fn: TaskFn[Payload]
    payload: Payload
    key_prefix: str = "shard"
    verb: str = "built"
    about: str = ""
    staging: str | None = None


@dataclass(frozen=True)
class Execution:
    """Where and how a job's units run: ``workers`` local processes (0: this process, no
    Dask) or an existing Dask ``scheduler``; ``say`` receives progress lines (None: none)."""

    workers: int
    scheduler: str | None = None
    say: Callable[[str], None] | None = None

    def __post_init__(self) -> None:
        check_workers(self.workers, self.scheduler)

    @classmethod
    def of(cls, workers: int | None = None, scheduler: str | None = None, progress: bool = True) -> Execution:
        """The job options' execution: ``workers`` None is one per core; ``progress`` lines go to stderr."""
        if not isinstance(progress, bool):
            raise SpecError(f"progress must be True or False, got {shorten(repr(progress))}")
        return cls(default_workers() if workers is None else workers, scheduler, to_stderr if progress else None)


def run_tasks(
    tasks: Sequence[ShardTask],
    task_fn: TaskFn[Payload],
    payload: Payload,
    sink: ShardSink,
    execution: Execution,
    on_done: Callable[[dict[str, Any]], None],
    key_prefix: str = "shard",
    on_episode: EpisodeReport | None = None,
) -> None:
    """Run ``task_fn(task, payload, sink)`` for every task on a local cluster (one
    single-threaded process per worker, at most one per task), on an existing scheduler, or
    in this process (``workers == 0``, or a single task without a scheduler: one task runs
    on one core either way, and starting a cluster, whose workers import everything again,
    costs more CPU than a small job's work); call ``on_done`` in the driver
    with each result as it finishes, and ``on_episode`` (on another thread with Dask) with
    the tasks' episode reports."""
    if not tasks:
        return
    workers, scheduler = execution.workers, execution.scheduler
    if not scheduler and (workers == 0 or len(tasks) == 1):
        for task in tasks:
            on_done(task_fn(task.reporting_to(on_episode), payload, sink))
        return
    import dask  # Dask is imported only by runs that use it
    from dask.distributed import Client, LocalCluster, as_completed

    with dask.config.set(LEAN_WORKERS), quiet_dask():
        cluster = client = None
        listening = on_episode is not None
        topic = f"dyana-progress-{uuid.uuid4().hex}"  # this run's alone, on a shared scheduler too

        def heard(event: tuple[float, Any]) -> None:  # on the client's event loop thread
            if listening and on_episode is not None:
                with contextlib.suppress(Exception):
                    msg = event[1]
                    on_episode(int(msg["first"]), int(msg["end"]), int(msg["done"]), int(msg["frames"]))

        try:
            with sigint_held():
                if scheduler:
                    client = connect(Client, scheduler)
                else:
                    preload_in_forkserver(task_fn)
                    cluster = LocalCluster(
                        n_workers=min(workers, len(tasks)),
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address="127.0.0.1:0",  # None still starts one on 8787 (dask/distributed#8136)
                        silence_logs=logging.CRITICAL,
                        preload=[__name__],  # dask_setup above: Ctrl-C is the driver's
                    )
                    client = Client(cluster)
            if on_episode is not None:
                client.subscribe_topic(topic, heard)
            futures = [
                client.submit(
                    reporting_task,
                    task_fn,
                    task,
                    payload,
                    sink,
                    topic if on_episode is not None else None,
                    key=f"{key_prefix}-{task.first:06d}-{task.end:06d}",
                    pure=False,
                )
                for task in tasks
            ]
            for future in as_completed(futures):
                on_done(future.result())
        except Exception as exc:
            failure = dask_failure(exc, scheduler)
            if failure is None:
                raise
            raise failure from None
        finally:
            listening = False
            with uninterrupted():
                if client is not None:
                    client.close()
                if cluster is not None:
                    cluster.close()


def reporting_task(
    task_fn: TaskFn[Payload], task: ShardTask, payload: Payload, sink: ShardSink, topic: str | None
) -> dict[str, Any]:
    """Worker side: ``task_fn``, its episode reports sent to the driver as Dask events on ``topic``."""
    if topic is None:
        return task_fn(task, payload, sink)
    from distributed import get_worker  # in a Dask worker, where distributed is loaded

    worker = get_worker()

    def report(first: int, end: int, done: int, frames: int) -> None:
        worker.log_event(topic, {"first": first, "end": end, "done": done, "frames": frames})

    return task_fn(task.reporting_to(report), payload, sink)
