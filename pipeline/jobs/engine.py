"""The job engine: everything around the shard tasks of a job that writes a folder.

Where the folder ends up is a :class:`Destination`: a local folder written in place
(:class:`LocalFolder`), or an object store (:mod:`pipeline.jobs.object_store`). The tasks
write their units' files where the output is, through the destination's ``sink`` (a
:class:`~pipeline.jobs.sink.ShardSink`, which a worker on any host can open); the engine
keeps the job's own files (lock, resume state, metadata) in ``destination.folder`` and
tells the destination which files each finished unit and the finished job left.

Build and eval (:mod:`pipeline.jobs.runner`) and the LeRobot export
(:mod:`pipeline.jobs.export`) differ only in what their folder holds when finished, a
:class:`Product`: how a finished or interrupted job is read back (its identity, the units
it may keep because their files still have their sizes and sha256, or the finished
result when the folder is complete and intact: "up to date"), how a finished unit is
recorded for resuming, and how the folder is finished (metadata written last).
:func:`run_folder_job` owns the rest, the same for every job:

- the folder lock (:mod:`pipeline.jobs.lock`), held from the first look at the folder
  to the last file written; stray temporaries of dead writers are removed;
- the units still to do run as Dask tasks or in this process (:mod:`pipeline.jobs.tasks`);
  when the work stages episodes (:attr:`~pipeline.jobs.tasks.Work.staging`), each task
  keeps its shard's finished episodes in the folder's ``.partial/`` under the job's key and
  this commit, and takes those an interrupted run left instead of computing them again
  (:mod:`catalog.tables.partial`); ``.partial/`` goes when the job finishes or is
  started over (``overwrite``);
- progress, passed as an argument (``say``: where lines go, or None for none): a line
  per finished episode, at most one per 2 s plus the last (:mod:`pipeline.jobs.progress`);
- the typed outcome: the product's result, whether it was up to date, units run and kept.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar

from catalog.export.layout import DYANA_META
from catalog.store.atomic import remove_stray_temps
from catalog.store.manifest import git_commit
from catalog.tables.partial import remove_partial
from pipeline.jobs.lock import LOCK_FILE, folder_lock
from pipeline.jobs.progress import Progress, Unit
from pipeline.jobs.sink import ShardSink
from pipeline.jobs.tasks import STAGED_EPISODES, Execution, Payload, ShardTask, Work, run_tasks
from schemas.errors import SpecError
from schemas.names import shorten

Range = tuple[int, int]


UnitT = TypeVar("UnitT", bound=Unit)
Result = TypeVar("Result")


@dataclass(frozen=True)
class Previous(Generic[UnitT, Result]):
    """What the folder already holds of this job: units it may keep (by episode range), and
    the finished result when the folder is complete and intact (then nothing is run)."""

    done: Mapping[Range, UnitT] = field(default_factory=dict)
    finished: Result | None = None


class Product(Protocol[UnitT, Result]):
    """What a job's folder holds apart from running its units."""

    def previous(self, folder: Path, commit: str | None, overwrite: bool) -> Previous[UnitT, Result]:
        """Read the folder (refusing another job's unless ``overwrite``)."""
        ...

    def unit(self, result: dict[str, Any]) -> UnitT:
        """A task's result as the unit's record."""
        ...

    def save(self, folder: Path, commit: str | None, done: Mapping[Range, UnitT]) -> None:
        """Record the finished units, for a killed run to resume from."""
        ...

    def finish(self, folder: Path, commit: str | None, units: Sequence[UnitT]) -> Result:
        """Write what marks the folder finished (last), from every unit in order."""
        ...

    def unit_files(self, unit: UnitT) -> list[str]:
        """The folder-relative files a finished unit leaves, its resume state last."""
        ...

    def result_files(self, result: Result) -> list[str]:
        """Every folder-relative file of the finished folder, what marks it finished last."""
        ...


class Destination(Protocol):
    """Where a job's folder ends up (see the module docstring)."""

    @property
    def folder(self) -> Path:
        """The local folder of the job's own files (for a local destination, the output)."""
        ...

    @property
    def sink(self) -> ShardSink:
        """Where the tasks write their units' files (sent with every task)."""
        ...

    def unit_done(self, paths: Sequence[str]) -> None:
        """A unit finished: these files of ``folder`` are complete (its resume state last)."""
        ...

    def job_done(self, paths: Sequence[str]) -> None:
        """The job finished (or was up to date): these are every file of the folder."""
        ...


@dataclass(frozen=True)
class LocalFolder:
    """A local folder, written in place: nothing to publish."""

    folder: Path

    @property
    def sink(self) -> ShardSink:
        """The folder itself, by its absolute path."""
        return ShardSink.folder(self.folder)

    def unit_done(self, paths: Sequence[str]) -> None:
        """Nothing: the files are where they belong."""

    def job_done(self, paths: Sequence[str]) -> None:
        """Nothing: the files are where they belong."""


@dataclass(frozen=True)
class Outcome(Generic[Result]):
    """What :func:`run_folder_job` did: the product's result; ``up_to_date`` when the folder
    already held this complete job; units run now and kept from an interrupted run."""

    result: Result
    up_to_date: bool
    units_run: int
    units_resumed: int


def prepare_folder(folder: Path) -> None:
    """Create the output folder, or one SpecError naming it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SpecError(f"{folder}: cannot create the output folder ({exc.strerror or exc})") from None


def refuse_links(folder: Path) -> None:
    """SpecError naming the first symbolic link inside ``folder`` (at any depth; the folder
    itself may be one): a job writes, renames and removes files in its folder, and a linked
    subfolder (``frames -> /elsewhere``) would take those writes and removals outside it."""
    for parent, dirs, files in os.walk(folder):
        for name in sorted(dirs) + sorted(files):
            path = Path(parent) / name
            if path.is_symlink():
                raise SpecError(
                    f"{shorten(str(path), 200)}: a symbolic link inside the output folder (to "
                    f"{shorten(os.readlink(path), 120)}); a job writes only real files and folders there: "
                    "remove the link or write elsewhere"
                )


#: Files that mark a folder as a LeRobot export (``catalog export`` writes both).
EXPORT_MARKERS = (DYANA_META, "meta/info.json")


def refuse_export_folder(folder: Path, what: str) -> None:
    """SpecError when ``folder`` holds a LeRobot export: a build or run written there would
    sit beside it, and a folder holds one kind of thing."""
    for marker in EXPORT_MARKERS:
        if (folder / marker).is_file():
            raise SpecError(
                f"{folder}: holds a LeRobot export ({marker}); a folder holds one kind of thing, "
                f"so write the {what} to another folder"
            )


def run_folder_job(
    destination: Destination,
    product: Product[UnitT, Result],
    work: Work[Payload],
    execution: Execution,
    *,
    overwrite: bool = False,
    total_frames: int | None = None,
    on_result: Callable[[dict[str, Any]], None] | None = None,
) -> Outcome[Result]:
    """Run the units of ``work`` not already done into the destination's folder and finish it (module docstring)."""
    folder = destination.folder
    created = not folder.exists()
    prepare_folder(folder)
    with folder_lock(folder):
        try:
            return _run_locked(destination, product, work, execution, overwrite, total_frames, on_result)
        except BaseException:
            if created:
                remove_if_bare(folder)
            raise


def remove_if_bare(folder: Path) -> None:
    """Remove ``folder`` (made by this job, which failed) if it holds only its lock file: a
    refused or failed start (an unreachable scheduler) leaves no folder behind. Called while
    the lock is held, so no other process has begun in it."""
    try:
        if [child.name for child in folder.iterdir()] == [LOCK_FILE]:
            (folder / LOCK_FILE).unlink()
            folder.rmdir()
    except OSError:
        pass  # something else appeared: leave it


def _run_locked(destination: Destination, product: Product[UnitT, Result], work: Work[Payload], execution: Execution,
                overwrite: bool, total_frames: int | None,
                on_result: Callable[[dict[str, Any]], None] | None) -> Outcome[Result]:
    """:func:`run_folder_job` once the folder's lock is held."""
    folder = destination.folder
    tasks, verb = work.tasks, work.verb
    ranges = [(task.first, task.end) for task in tasks]
    refuse_links(folder)
    # under the lock, before this process writes anything: a temp named with our pid is a
    # dead writer's whose pid was reused (a fresh container rerun gets the same pid)
    remove_stray_temps(folder, keep_own=False)
    if overwrite:
        remove_partial(folder)
    commit = git_commit()
    previous = product.previous(folder, commit, overwrite)
    if previous.finished is not None:
        remove_partial(folder)  # what a run that died after finishing left
        destination.job_done(product.result_files(previous.finished))
        return Outcome(previous.finished, True, 0, len(previous.done))
    done = {key: unit for key, unit in previous.done.items() if key in set(ranges)}
    resumed = len(done)
    todo = staged(work, commit, [task for task in tasks if (task.first, task.end) not in done])
    say = execution.say
    episodes = sum(end - first for first, end in ranges)
    if say is not None and work.about:
        say(work.about)
    meter = None if say is None else Progress(len(ranges), episodes, total_frames=total_frames, say=say)
    if meter is not None and say is not None and done:
        say(f"resuming: {len(done)} of {len(ranges)} shards already {verb}")
        meter.resumed([done[key] for key in sorted(done)])

    def on_done(result: dict[str, Any]) -> None:
        unit = product.unit(result)
        done[(unit.first, unit.end)] = unit
        product.save(folder, commit, done)
        destination.unit_done(product.unit_files(unit))
        if on_result is not None:
            on_result(result)
        if say is not None and result.get(STAGED_EPISODES):
            say(f"shard {unit.first}-{unit.end - 1}: {result[STAGED_EPISODES]} of its {unit.end - unit.first} "
                f"episodes taken from the interrupted run")
        if meter is not None:
            meter.update(unit)

    try:
        run_tasks(todo, work.task_fn, work.payload, destination.sink, execution, on_done, work.key_prefix,
                  on_episode=None if meter is None else meter.episode)
    finally:
        remove_stray_temps(folder)  # what workers that died (killed, out of memory) left behind
    result = product.finish(folder, commit, [done[key] for key in ranges])
    remove_partial(folder)
    destination.job_done(product.result_files(result))
    return Outcome(result, False, len(todo), resumed)


def staged(work: Work[Any], commit: str | None, tasks: list[ShardTask]) -> list[ShardTask]:
    """``tasks``, staging their finished episodes under the job's key (its identity and this
    commit: :mod:`catalog.tables.partial`) when ``work`` stages them."""
    if work.staging is None:
        return tasks
    key = hashlib.sha256(f"{work.staging}\n{commit}".encode()).hexdigest()
    return [dataclasses.replace(task, staging=key) for task in tasks]
