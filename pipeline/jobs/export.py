"""``catalog export DIR [DIR ...] --format lerobot|lerobot-v2.1 --out OUT``: built slices
or evaluated runs as one LeRobot dataset, run by the job engine (:mod:`pipeline.jobs.engine`).

The format (units, parts, metadata) is :mod:`catalog.export.lerobot`'s; here is the
export as a job: its units are the source's shards, run as Dask tasks or in this
process, under the folder lock, with progress per exported episode. The driver lives in
``pipeline`` (not beside the format in ``catalog``) because running jobs (processes, Dask,
the lock) is this layer's; ``catalog`` stays a library of formats and readers.

Several sources become one dataset, their episodes renumbered in the order given (each
episode keeps its source's slice hash and episode index); the same folder twice (the same
slice hash) is refused, and so are sources of different image sizes.

A folder holds one export: an existing finished export of the same sources and settings
whose every listed file still has its size and sha256 is "up to date" (a damaged one is
exported again); an interrupted export of the same source and settings resumes from the
units whose files are intact; anything else in ``OUT`` is refused unless ``--overwrite``
(which only ever deletes a folder that is a Dyana export).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from catalog.export.layout import DYANA_META
from catalog.export.lerobot import (
    WORK_DIR,
    ExportError,
    ExportPlan,
    ExportSettings,
    Json,
    Part,
    Unit,
    job_identity,
    part_path,
    read_part,
)
from catalog.export.meta import assemble, tasks_of
from catalog.export.unit import export_unit
from catalog.store.atomic import atomic_write_text, remove_stray_temps
from catalog.store.records import FileRecord
from catalog.store.storage import is_remote
from catalog.tables.reader import FolderReader, open_folder
from pipeline.jobs.engine import LocalFolder, Previous, Range, run_folder_job
from pipeline.jobs.lock import LOCK_FILE, FolderBusy
from pipeline.jobs.sink import ShardSink
from pipeline.jobs.spec import Storage
from pipeline.jobs.state import file_intact
from pipeline.jobs.tasks import Execution, ShardTask, Work, check_workers
from schemas.errors import DyanaError
from schemas.names import shorten

JOB_FILE = "job.json"


@dataclass(frozen=True)
class ExportReport:
    """What :func:`export` did: the folder, its episodes and frames, units exported now and
    kept from an interrupted export, whether it was up to date, and the seconds taken."""

    out: Path
    episodes: int
    frames: int
    units_done: int
    units_resumed: int
    up_to_date: bool
    seconds: float


@dataclass(frozen=True)
class Exported:
    """A finished export's size."""

    episodes: int
    frames: int


def _content(out: Path) -> list[Path]:
    """What ``out`` holds besides the export's work folder and the folder lock."""
    return [child for child in out.iterdir() if child.name not in (WORK_DIR, LOCK_FILE)]


def _is_export(out: Path) -> bool:
    return (out / DYANA_META).is_file() or (out / WORK_DIR / JOB_FILE).is_file()


def check_foreign(out: Path) -> None:
    """Refuse, before writing anything (not even the lock), a folder holding something other than an export."""
    if out.exists() and not out.is_dir():
        raise ExportError(f"{shorten(os.fspath(out))}: exists and is not a folder")
    if (out / "catalog.json").is_file():
        raise ExportError(f"{shorten(os.fspath(out))}: holds a Dyana build or run (catalog.json); "
                          "a folder holds one kind of thing, so export to another folder")
    if out.is_dir() and not _is_export(out) and _content(out):
        raise ExportError(f"{shorten(os.fspath(out))}: not empty and not a Dyana export; choose a new folder")


def _remove_work(folder: Path) -> None:
    """Remove the work folder of a finished export (part records, the job record)."""
    work = folder / WORK_DIR
    if work.is_dir():
        shutil.rmtree(work)


def _read_json(path: Path) -> Json:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def files_intact(out: Path, files: Json) -> bool:
    """Every file a ``meta/dyana.json`` lists is there with its size and sha256."""
    if not isinstance(files, dict):
        return False
    try:
        records = [FileRecord.from_dict({"path": path, **entry}) for path, entry in files.items()]
    except (TypeError, DyanaError):
        return False
    return all(file_intact(out, record) for record in records)


#: The export's folders that LeRobot and ``datasets`` read whole: a file there that
#: ``meta/dyana.json`` does not list would be loaded as part of the dataset.
READ_FOLDERS = ("data", "videos", "meta")


def stray_files(out: Path, files: Json) -> list[Path]:
    """Files under the export's :data:`READ_FOLDERS` that its ``meta/dyana.json`` does not list."""
    listed = set(files) if isinstance(files, dict) else set()
    listed.add(DYANA_META)
    return sorted(path for name in READ_FOLDERS for path in (out / name).rglob("*")
                  if path.is_file() and path.relative_to(out).as_posix() not in listed)


@dataclass(frozen=True)
class LeRobotProduct:
    """A LeRobot export folder as the engine's product (see the module docstring)."""

    readers: tuple[FolderReader, ...]
    settings: ExportSettings
    plan: ExportPlan
    identity: Mapping[str, Json]

    def previous(self, folder: Path, commit: str | None, overwrite: bool) -> Previous[Part, Exported]:
        check_foreign(folder)
        # Under the folder lock, before this process writes anything: a temp named with this
        # process's pid is a dead writer's whose pid was reused (a fresh pid namespace gives a
        # rerun the killed driver's pid); the engine already removed the other dead ones.
        remove_stray_temps(folder, keep_own=False)
        finished, job = folder / DYANA_META, folder / WORK_DIR / JOB_FILE
        meta = _read_json(finished) if finished.is_file() else None
        same = isinstance(meta, dict) and meta.get("job") == self.identity and not overwrite
        if same and isinstance(meta, dict) and files_intact(folder, meta.get("files")) \
                and not stray_files(folder, meta.get("files")):
            _remove_work(folder)  # a driver killed after dyana.json, before it cleaned up
            return Previous(finished=Exported(sum(r.manifest.episodes for r in self.readers),
                                              sum(r.manifest.frames for r in self.readers)))
        if _content(folder):
            resuming = job.is_file() and _read_json(job) == self.identity and not finished.is_file()
            if not (resuming or same):
                if not overwrite:
                    raise ExportError(f"{shorten(os.fspath(folder))}: holds an export of another source or settings; "
                                      "use --overwrite to replace it")
                for child in _content(folder):
                    shutil.rmtree(child) if child.is_dir() else child.unlink()
                for child in (folder / WORK_DIR).glob("part-*.json"):
                    child.unlink()
            if same:  # this export, damaged: its parts are gone, so every unit is exported again
                finished.unlink()
        atomic_write_text(job, json.dumps(dict(self.identity), sort_keys=True) + "\n")
        done: dict[Range, Part] = {}
        for number in range(len(self.plan.units)):
            part = read_part(folder, number)
            if part is not None and all(file_intact(folder, f) for f in part.files):
                done[(part.first, part.end)] = part
        return Previous(done)

    def unit(self, result: dict[str, Any]) -> Part:
        return Part.from_dict(result["part"])

    def save(self, folder: Path, commit: str | None, done: Mapping[Range, Part]) -> None:
        """Nothing: each unit's part record, written by the unit itself, is the resume state."""

    def unit_files(self, unit: Part) -> list[str]:
        return [f.path for f in unit.files] + [part_path(Path(), unit.shard).as_posix()]

    def result_files(self, result: Exported) -> list[str]:
        meta = _read_json(Path(self.plan.out) / DYANA_META)
        files = meta.get("files", {}) if isinstance(meta, dict) else {}
        return [*sorted(files), DYANA_META]

    def finish(self, folder: Path, commit: str | None, units: Sequence[Part]) -> Exported:
        assemble(folder, self.readers, self.settings, units, self.plan.tasks, self.identity, self.plan.height,
                 self.plan.width)
        meta = _read_json(folder / DYANA_META)
        for path in stray_files(folder, meta.get("files") if isinstance(meta, dict) else None):
            path.unlink()  # a stray file in data/, videos/ or meta/ would be read as part of the dataset
        _remove_work(folder)
        return Exported(sum(len(p.episodes) for p in units), sum(p.frames for p in units))


def export_shard(task: ShardTask, plan: ExportPlan, sink: ShardSink) -> dict[str, Any]:
    """Worker side: export the source shard of ``task`` (into the plan's folder); its part record."""
    return {"part": export_unit(plan, task.first, task.report).to_dict()}


def _plan(readers: Sequence[FolderReader], names: Sequence[str], target: Path, settings: ExportSettings) -> ExportPlan:
    """The export's units in order (sources as given, each's shards in order), after
    refusing what cannot be one dataset: a source twice, no episodes, another image size."""
    seen: dict[str, str] = {}
    sizes = set()
    for reader, name in zip(readers, names):
        manifest = reader.manifest
        if manifest.hash in seen:
            raise ExportError(f"{shorten(name)}: the same build as {shorten(seen[manifest.hash])} (slice hash "
                              f"{manifest.hash}): give each source once")
        seen[manifest.hash] = name
        if manifest.episodes == 0:
            raise ExportError(f"{shorten(name)}: nothing to export (no episodes)")
        size = int(manifest.settings.get("resolution", 0))
        if size <= 0 or size % 2:
            raise ExportError(f"{shorten(name)}: video export needs an even image size, got {size}")
        sizes.add(size)
        if len(sizes) > 1:
            raise ExportError(f"{shorten(name)}: its images are {size} px, the sources before it "
                              f"{min(sizes - {size})} px: one export holds one image size")
    units, episode, index = [], 0, 0
    for k, reader in enumerate(readers):
        for shard in reader.manifest.shards:
            units.append(Unit(k, shard.first, episode, index, shard.end - shard.first, shard.frames))
            episode += shard.end - shard.first
            index += shard.frames
    size = sizes.pop()
    return ExportPlan(tuple(str(r.root) for r in readers), tuple(r.manifest.hash for r in readers), os.fspath(target),
                      settings, tasks_of(readers), size, size, tuple(units))


def refuse_nested(sources: Sequence[str], out: Path) -> None:
    """ExportError when ``out`` is a source folder, lies inside one, or holds one: the export
    would write into (or, replacing its folder, delete) what it reads, and ``catalog verify``
    of that source would then fail on files its manifest does not list."""
    target = out.resolve()
    for name in sources:
        if is_remote(name):
            continue
        folder = Path(name).resolve()
        if target == folder or folder in target.parents or target in folder.parents:
            where = "is" if target == folder else "lies inside" if folder in target.parents else "holds"
            raise ExportError(f"--out {shorten(str(out))} {where} the source {shorten(name)}: "
                              "write the export to a folder apart from every source")


def export(
    source: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    settings: ExportSettings,
    *,
    workers: int = 1,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
) -> ExportReport:
    """Export built slice or run folders (one, or a sequence) into ``out`` as one dataset
    (see the module docstring): ``workers`` processes (1: in this process), progress
    lines to ``progress``."""
    check_workers(workers, None)
    if is_remote(out):  # else a local folder named "s3:" would be made
        raise ExportError(f"--out {shorten(str(out))}: an export is written to a local folder (object-storage "
                          "outputs are not supported yet): export here, then copy it")
    storage = Storage(out, overwrite)  # the folder name and overwrite, checked as a build's
    items = [source] if isinstance(source, (str, os.PathLike)) else source if isinstance(source, (list, tuple)) else None
    if items is None or not all(isinstance(item, (str, os.PathLike)) for item in items):
        raise ExportError(f"source must be a folder or a list of folders, got {shorten(repr(source))}")
    if not isinstance(settings, ExportSettings):
        raise ExportError(f"settings must be an ExportSettings, got {shorten(repr(settings))}")
    names = [os.fspath(item) for item in items]
    if not names:
        raise ExportError("nothing to export: give at least one source folder")
    refuse_nested(names, Path(out))
    start = time.perf_counter()
    readers = tuple(open_folder(name, verify="sha256") for name in names)
    target = storage.folder
    check_foreign(target)
    plan = _plan(readers, names, target, settings)
    product = LeRobotProduct(readers, settings, plan, job_identity(readers, settings))
    tasks = tuple(ShardTask(readers[u.source].manifest.slice, u.episode, u.episode + u.episodes) for u in plan.units)
    execution = Execution(0 if workers <= 1 else workers, None, progress)
    work = Work(tasks, export_shard, plan, key_prefix="export", verb="exported")
    existed = target.exists()
    fresh = not existed or not any(target.iterdir())
    try:
        outcome = run_folder_job(LocalFolder(target), product, work, execution, overwrite=overwrite,
                                 total_frames=sum(u.frames for u in plan.units))
    except FolderBusy:
        raise  # another process is writing the folder: nothing here is this run's
    except DyanaError:
        # a source found damaged mid-export (its sha256 is checked as it is read): an export
        # this run began leaves nothing, no work folder or part a later run would take up
        if fresh and target.is_dir():
            if existed:
                for child in target.iterdir():
                    shutil.rmtree(child) if child.is_dir() else child.unlink()
            else:
                shutil.rmtree(target)
        raise
    return ExportReport(target, outcome.result.episodes, outcome.result.frames, outcome.units_run,
                        outcome.units_resumed, outcome.up_to_date, time.perf_counter() - start)
