"""Sharded jobs that leave a ``catalog.json`` folder: `pipeline build` and `pipeline eval`.

A :class:`Job` names what its folder will hold (slice, seed, settings, extra manifest keys
such as a specs file's hash, shard ranges) and a worker function that writes one shard.
:func:`run_job` is the one call that runs such a job, given its
:class:`~pipeline.jobs.tasks.Execution` and :class:`~pipeline.jobs.spec.Storage` (the
parts of a :class:`~pipeline.jobs.spec.JobSpec`): into a local folder, or into an object
store (:mod:`pipeline.jobs.object_store`), on the job engine
(:func:`pipeline.jobs.engine.run_folder_job`, with :class:`ManifestProduct` saying what
such a folder holds):

- the folder holds one job (:mod:`pipeline.jobs.state`): a ``catalog.json`` (or a killed
  run's ``.build-state.json``) describing anything else is refused with a message naming
  what differs, unless ``overwrite``; a second process on the folder is refused by the
  folder lock (:mod:`pipeline.jobs.lock`);
- stray temporaries of dead processes are removed; finished shards of an interrupted
  run of the same job (same package and library versions: the rule of
  :func:`pipeline.jobs.state.code_decision`) whose files still match their sha256 are kept,
  so a killed run resumes, and a complete identical folder is reported up to date; when
  another commit wrote them, one sample shard is rebuilt and compared first
  (:mod:`pipeline.jobs.resume`);
- the shards run as Dask tasks or in this process (:mod:`pipeline.jobs.tasks`); into a
  local folder, each task stages its shard's finished episodes in ``.partial/``, so a run
  interrupted mid-shard resumes that shard from its last staged episode
  (:mod:`catalog.tables.partial`, :func:`staging_key`); an object store's shards are
  uploaded whole from a worker's scratch folder, so they are redone whole;
- progress lines go to stderr per finished episode, at most one per 2 s plus the last
  (:class:`pipeline.jobs.progress.Progress`);
- ``stats.json`` (normalisation statistics of states and actions) is merged from the
  partial statistics each task returned (``result["partial_stats"]``, computed in the
  worker from the frames file it wrote, kept in the resume state with the job's other
  :attr:`Job.keep` keys; a shard without them is read once), then ``catalog.json`` is
  written last (one way, :meth:`catalog.store.manifest.Manifest.create`), then files of a
  replaced job are removed.

The manifest's hash covers the slice, seed, settings, statistics and the ordered file
hashes, so the worker count, the scheduler and interruptions cannot change it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic

from catalog.store.hashing import canonical_json, sha256_bytes
from catalog.store.manifest import MANIFEST_NAME, CodeInfo, Manifest, load_manifest, write_manifest
from catalog.store.records import ShardRecord, shard_like_files
from catalog.store.storage import as_location, listed_sizes, where
from catalog.store.versions import installed_versions
from catalog.tables.reader import ShardReader
from catalog.tables.stats import PartialStats, Stats, merge_partials, shard_partial, write_stats
from pipeline.jobs.audit import audit_records, remove_unlisted_audit
from pipeline.jobs.engine import Destination, LocalFolder, Previous, run_folder_job
from pipeline.jobs.object_store import ObjectStore, prepare_remote, remote_job
from pipeline.jobs.resume import check_sample
from pipeline.jobs.spec import Storage
from pipeline.jobs.state import STATE_FILE, Identity, Range, identity_of, previous_work, save_state
from pipeline.jobs.tasks import Execution, Payload, ShardTask, TaskFn, Work, default_workers, shard_ranges
from schemas.errors import ShardError
from schemas.versions import CODE_VERSION

__all__ = ["PARTIAL_STATS", "Execution", "Job", "JobResult", "ShardTask", "Storage", "default_workers",
           "remove_unlisted_shards", "run_job", "shard_ranges"]

#: The key of a task result holding its shard's partial statistics
#: (:meth:`catalog.tables.stats.PartialStats.to_dict`, from :func:`catalog.tables.stats.written_partial`).
PARTIAL_STATS = "partial_stats"


@dataclass(frozen=True)
class Job(Generic[Payload]):
    """A sharded job (where it is written is the caller's :class:`~pipeline.jobs.spec.Storage`).
    ``task_fn(task, payload, sink)`` runs in a worker and returns a dict with the shard's
    ``record`` (a ShardRecord dict), its :data:`PARTIAL_STATS` when the job has statistics,
    and anything else the caller's ``on_result`` wants (timing). ``keep``: the result keys
    kept in the resume state and returned in :attr:`JobResult.kept` (an eval's counts), so
    a resumed shard needs no reading. ``extra`` are the manifest's top-level keys beyond the
    contract's; with ``settings``, ``slice``, ``seed`` and the shard ranges they say what
    the folder holds. ``audit_dir``: the folder of the tasks' audit trail files (one per
    shard, :func:`pipeline.jobs.audit.audit_path`), listed in the manifest's ``audit``."""

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
    audit_dir: str | None = None
    keep: tuple[str, ...] = (PARTIAL_STATS,)
    #: How big the job is, said before it starts (:attr:`pipeline.jobs.tasks.Work.about`).
    about: str = ""
    ranges: tuple[Range, ...] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ranges", tuple((t.first, t.end) for t in self.tasks))

    @property
    def episodes(self) -> int:
        return self.ranges[-1][1] if self.ranges else 0

    def work(self) -> Work[Payload]:
        """The job's units, as the engine runs them."""
        return Work(self.tasks, self.task_fn, self.payload, self.key_prefix, self.verb, self.about)

    def identity(self) -> Identity:
        """What the folder must already hold for this job to reuse it."""
        return identity_of(self.slice_name, self.seed, self.episodes, self.ranges, self.settings, self.extra)


@dataclass(frozen=True)
class JobResult:
    """What :func:`run_job` did: the folder's manifest; ``up_to_date`` when the folder
    already held this complete job (nothing was run); shards run now and kept from an
    interrupted run; ``kept``: each shard's :attr:`Job.keep` values, in shard order (empty
    when up to date; a shard kept from an older state may lack them)."""

    manifest: Manifest
    up_to_date: bool
    shards_run: int = 0
    shards_resumed: int = 0
    kept: tuple[Mapping[str, Any], ...] = ()


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


@dataclass(frozen=True)
class ManifestProduct:
    """A ``catalog.json`` folder (a built slice or a run) as the engine's product. ``store``:
    where the tasks' files are when not in the folder (an object store's URL, as a UPath):
    a finished shard is kept there while its objects have their recorded sizes, and the
    audit records (and statistics of shards without partial ones) are read from there.
    ``say``: where the sample check's note goes. ``kept``: the :attr:`Job.keep` values of
    the shards' task results by range, filled as the job runs (the one mutable part)."""

    job: Job[Any]
    store: Path | None = None
    say: Callable[[str], None] | None = None
    kept: dict[Range, dict] = field(default_factory=dict)

    def previous(self, folder: Path, commit: str | None, overwrite: bool) -> Previous[ShardRecord, Manifest]:
        intact = None
        if self.store is not None:
            sizes = listed_sizes(self.store)
            intact = lambda record: all(sizes.get(f.path) == f.size for f in record.files.values())  # noqa: E731
        job = self.job
        work = previous_work(folder, job.identity(), job.with_stats, commit, overwrite, intact)
        if work.sample:
            check_sample([work.done[key] for key in sorted(work.done)], job.tasks, job.task_fn, job.payload,
                         (work.recorded_commit, commit), where(folder if self.store is None else self.store), self.say)
        self.kept.update(work.kept)
        return Previous(work.done, load_manifest(folder) if work.complete else None)

    def unit(self, result: dict[str, Any]) -> ShardRecord:
        record = ShardRecord.from_dict(result["record"])
        self.kept[(record.first, record.end)] = {key: result[key] for key in self.job.keep if key in result}
        return record

    def save(self, folder: Path, commit: str | None, done: Mapping[Range, ShardRecord]) -> None:
        save_state(folder, self.job.identity(), commit, done, self.kept)

    def statistics(self, files: Path, units: Sequence[ShardRecord]) -> Stats:
        """The units' statistics, merged from their partial ones; a unit without them (a
        state written before they were kept) or with unreadable ones is read."""
        parts = []
        for unit in units:
            try:
                parts.append(PartialStats.from_dict(self.kept[(unit.first, unit.end)][PARTIAL_STATS]))
            except (KeyError, ValueError):
                parts.append(shard_partial(ShardReader(as_location(files), unit, rollout=False, verify="size")))
        return merge_partials(parts)

    def unit_files(self, unit: ShardRecord) -> list[str]:
        return [f.path for f in unit.files.values()] + [STATE_FILE]

    def result_files(self, result: Manifest) -> list[str]:
        stats = [] if result.stats is None else [result.stats.path]
        audit = [record.path for record in result.audit or ()]
        return [path for path, _, _ in result.files()] + stats + audit + [MANIFEST_NAME]

    def finish(self, folder: Path, commit: str | None, units: Sequence[ShardRecord]) -> Manifest:
        """``stats.json``, then ``catalog.json``, then the files of a replaced job go."""
        job = self.job
        files = folder if self.store is None else self.store
        if self.store is not None:
            check_stored(self.store, units)
        stats = write_stats(folder, self.statistics(files, units)) if job.with_stats else None
        audit = None if job.audit_dir is None else audit_records(files, job.audit_dir, [u.episodes for u in units])
        manifest = Manifest.create(job.slice_name, job.seed, job.settings, list(units),
                                   code=CodeInfo(CODE_VERSION, commit), extra=job.extra, stats=stats, audit=audit,
                                   versions=installed_versions())
        write_manifest(folder, manifest)
        remove_unlisted_shards(folder, manifest)
        if job.audit_dir is not None:
            remove_unlisted_audit(folder, job.audit_dir, manifest)
        (folder / STATE_FILE).unlink(missing_ok=True)
        return manifest


def check_stored(store: Path, units: Sequence[ShardRecord]) -> None:
    """ShardError unless every file of ``units`` is in the object store ``store`` at its
    recorded size (listed afresh: other hosts uploaded them)."""
    sizes = listed_sizes(store)
    missing = [f.path for unit in units for f in unit.files.values() if sizes.get(f.path) != f.size]
    if missing:
        raise ShardError(f"{where(store)}/{missing[0]}: not in the object store at its recorded size "
                         f"({len(missing)} file(s) of finished shards); rerun the same command to rebuild them")


def run_job(
    job: Job[Payload],
    execution: Execution,
    storage: Storage,
    on_result: Callable[[dict[str, Any]], None] | None = None,
) -> JobResult:
    """Run ``job`` into ``storage``: its local folder (see the module docstring), or its
    object-store URL (:mod:`pipeline.jobs.object_store`: the workers upload the shards, the
    driver keeps the job's own files in a staging folder and publishes them); ``on_result``
    hears each finished task's result in the driver."""
    if not storage.remote:
        return _run(job, LocalFolder(storage.folder), None, execution, storage.overwrite, on_result)
    url = str(storage.out)
    with remote_job(url) as (staging, remote):
        def sample(manifest: Manifest, commit: str | None) -> None:
            check_sample(manifest.shards, job.tasks, job.task_fn, job.payload, (manifest.code.commit, commit), url,
                         execution.say)

        held = prepare_remote(url, staging, remote, job.identity(), storage.overwrite, sample)
        if held is not None:
            return JobResult(held, True)
        result = _run(job, ObjectStore(staging, remote, url), remote, execution, storage.overwrite, on_result)
    return dataclasses.replace(result, up_to_date=False)  # the URL did not hold it: it was published now


def staging_key(job: Job[Any]) -> str:
    """The digest a local job's tasks stage their finished episodes under (with the commit,
    :func:`pipeline.jobs.engine.staged`): its identity (slice, settings with the dataset
    version, extra keys, shard ranges) and the code and library versions that write its bytes."""
    return sha256_bytes(canonical_json({"identity": job.identity(), "code": CODE_VERSION,
                                        "versions": installed_versions()}).encode())


def _run(job: Job[Payload], destination: Destination, store: Path | None, execution: Execution, overwrite: bool,
         on_result: Callable[[dict[str, Any]], None] | None) -> JobResult:
    """The engine's run of ``job`` into ``destination`` (``store``: where its tasks' files are,
    when not in the destination's folder: :class:`ManifestProduct`)."""
    product = ManifestProduct(job, store, execution.say)
    work = job.work() if store is not None else dataclasses.replace(job.work(), staging=staging_key(job))
    outcome = run_folder_job(destination, product, work, execution, overwrite=overwrite, on_result=on_result)
    kept = () if outcome.up_to_date else tuple(product.kept.get(r, {}) for r in job.ranges)
    return JobResult(outcome.result, outcome.up_to_date, outcome.units_run, outcome.units_resumed, kept)
