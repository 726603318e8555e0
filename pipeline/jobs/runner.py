"""One driver for sharded jobs: `pipeline build`, `pipeline eval` and anything after them.

A :class:`Job` names an output folder, what it will hold (slice, seed, settings, extra
manifest keys such as a specs file's hash, shard ranges) and a worker function that writes one
shard. :func:`run_job` owns everything around the shards:

- the folder holds one job (:mod:`pipeline.jobs.state`): a ``catalog.json`` (or a killed
  run's ``.build-state.json``) describing anything else is refused with a message naming
  what differs, unless ``overwrite``; a second process on the folder is refused by the
  folder lock (:mod:`pipeline.jobs.lock`);
- stray temporaries of dead processes are removed; finished shards of an interrupted
  run of the same job (same code commit) whose files still match their sha256 are kept,
  so a killed run resumes, and a complete identical folder is reported up to date;
- the shards run as Dask tasks or in this process (:mod:`pipeline.jobs.tasks`);
- progress lines go to stderr per finished episode, at most one per 2 s plus the last
  (:class:`pipeline.jobs.progress.Progress`);
- ``stats.json`` (normalisation statistics of states and actions) is computed from the
  finished shards, then ``catalog.json`` is written last (one way,
  :meth:`catalog.manifest.Manifest.create`), then files of a replaced job are removed.

The manifest's hash covers the slice, seed, settings, statistics and the ordered file
hashes, so the worker count, the scheduler and interruptions cannot change it.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic

from catalog.atomic import remove_stray_temps
from catalog.manifest import CodeInfo, Manifest, git_commit, load_manifest, write_manifest
from catalog.records import ShardRecord, shard_like_files
from catalog.stats import compute_stats, write_stats
from pipeline.jobs.lock import folder_lock
from pipeline.jobs.progress import Progress
from pipeline.jobs.state import STATE_FILE, Identity, Range, identity_of, previous_work, save_state
from pipeline.jobs.tasks import Payload, ShardTask, TaskFn, check_workers, default_workers, run_tasks, shard_ranges
from schemas.errors import SpecError
from schemas.versions import CODE_VERSION

__all__ = ["Job", "JobResult", "ShardTask", "default_workers", "remove_unlisted_shards", "run_job", "shard_ranges"]


@dataclass(frozen=True)
class Job(Generic[Payload]):
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
    task_fn: TaskFn[Payload]
    payload: Payload
    verb: str = "built"
    key_prefix: str = "shard"
    with_stats: bool = True
    ranges: tuple[Range, ...] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ranges", tuple((t.first, t.end) for t in self.tasks))

    @property
    def episodes(self) -> int:
        return self.ranges[-1][1] if self.ranges else 0

    def identity(self) -> Identity:
        """What the folder must already hold for this job to reuse it."""
        return identity_of(self.slice_name, self.seed, self.episodes, self.ranges, self.settings, self.extra)


@dataclass(frozen=True)
class JobResult:
    """What :func:`run_job` did: the folder's manifest; ``up_to_date`` when the folder
    already held this complete job (nothing was run); shards run now and kept from an
    interrupted run."""

    manifest: Manifest
    up_to_date: bool
    shards_run: int = 0
    shards_resumed: int = 0


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
    job: Job[Payload],
    *,
    workers: int,
    scheduler: str | None = None,
    progress: bool = True,
    overwrite: bool = False,
    on_result: Callable[[dict[str, Any]], None] | None = None,
) -> JobResult:
    """Run ``job`` into its folder (see the module docstring)."""
    check_workers(workers, scheduler)
    folder = job.folder
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SpecError(f"{folder}: cannot create the output folder ({exc.strerror or exc})") from None
    with folder_lock(folder):
        remove_stray_temps(folder)
        commit = git_commit()
        wanted = job.identity()
        previous = previous_work(folder, wanted, job.with_stats, commit, overwrite)
        if previous.complete:
            return JobResult(load_manifest(folder), True, 0, len(previous.done))
        done = {key: record for key, record in previous.done.items() if key in set(job.ranges)}
        resumed = len(done)
        todo = [task for task in job.tasks if (task.first, task.end) not in done]

        meter = Progress(len(job.ranges), job.episodes) if progress else None
        if meter is not None and done:
            print(f"resuming: {len(done)} of {len(job.ranges)} shards already {job.verb}", file=sys.stderr)
            meter.resumed([done[key] for key in sorted(done)])

        def on_done(result: dict[str, Any]) -> None:
            record = ShardRecord.from_dict(result["record"])
            done[(record.first, record.end)] = record
            save_state(folder, wanted, commit, done)
            if on_result is not None:
                on_result(result)
            if meter is not None:
                meter.update(record)

        try:
            run_tasks(todo, job.task_fn, job.payload, folder, workers, scheduler, on_done, job.key_prefix,
                      on_episode=meter.episode if meter is not None else None)
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
    return JobResult(manifest, False, len(todo), resumed)
