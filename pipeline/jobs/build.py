"""`pipeline build`: a slice's shards, resumable and byte-reproducible.

Each shard task (:func:`build_shard`) runs the episode stage, renders, JPEG-encodes and
writes Parquet + MCAP under temporary names, then renames, where the job's output is (a
folder, or uploaded to the object store from the worker: :mod:`pipeline.jobs.sink`). Everything around the shards
(the folder's one-job rule, resume, progress, Dask, statistics, the manifest, a local
folder or an object store) is :func:`pipeline.jobs.runner.run_job`'s.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path
from typing import Any

from catalog.store.manifest import Manifest
from catalog.tables.stats import written_partial
from pipeline.jobs.progress import announcement
from pipeline.jobs.runner import PARTIAL_STATS, Job, JobResult, run_job
from pipeline.jobs.sink import ShardSink
from pipeline.jobs.spec import JobSpec, job_spec
from pipeline.jobs.tasks import STAGED_EPISODES, ShardTask, shard_ranges
from schemas.errors import InfeasibleError, SpecError
from schemas.settings import BuildSettings
from schemas.spec import EpisodeSpec

DEFAULT_SHARD_SIZE = 128


def build_shard(task: ShardTask, settings: BuildSettings, sink: ShardSink) -> dict:
    """Worker side: write one shard where the job's output is; its record as a plain dict."""
    from pipeline.stages.record import write_ground_truth_shard

    with sink.writing() as folder:
        record, taken = write_ground_truth_shard(task.specs(), task.first, task.end, settings, folder,
                                                 task.partial(folder))
        partial = written_partial(folder, record)  # while the files are on this host
    return {"record": record.to_dict(), PARTIAL_STATS: partial, STAGED_EPISODES: taken}


def build(slice_name: str | None, out: str | Path, **options: Any) -> Manifest:
    """Build a slice (or a specs file) into ``out/<slice>/`` and return its manifest;
    the options are :func:`build_job`'s."""
    return build_job(slice_name, out, **options).manifest


def build_job(slice_name: str | None, out: str | Path, **options: Any) -> JobResult:
    """Build a slice (or a specs file) into ``out/<slice>/``: its manifest, and whether
    the folder already held this complete build (then nothing is redone).

    The keyword options are the CLI's flags (:func:`pipeline.jobs.spec.job_spec`):
    ``episodes``, ``shard_size`` (default 128), ``specs_path`` (``--specs``),
    ``resolution`` (224), ``renderer`` (``window``: dataset 5.0.0; ``full`` is refused),
    ``formats``, ``workers`` (default one per core; 0: in this process, no Dask),
    ``scheduler``, ``progress`` (True) and ``overwrite`` (a folder holding another build
    is refused without it). :func:`run_build` takes the :class:`~pipeline.jobs.spec.JobSpec`."""
    return run_build(job_spec(slice_name, out, options, shard_size=DEFAULT_SHARD_SIZE))


def run_build(spec: JobSpec) -> JobResult:
    """Run a build's :class:`~pipeline.jobs.spec.JobSpec` (module docstring)."""
    selection, storage = spec.selection, spec.storage
    slice_name = selection.slice_name
    extra: dict[str, str] = {}
    if selection.specs_path is not None:
        specs = _load_user_specs(selection.specs_path, slice_name)
        slice_name = specs[0].slice
        seed = specs[0].seed if len({s.seed for s in specs}) == 1 else None
        specs = specs[:selection.first_episodes(len(specs))]
        lines = [s.to_json() for s in specs]
        obstacles = any(s.obstacles for s in specs)
        specs_json: list[str] | None = lines
        extra["specs_sha256"] = hashlib.sha256("\n".join(lines).encode()).hexdigest()
        total = len(specs)
    else:
        from schemas.slices import get_slice

        if slice_name is None:
            raise SpecError("give --slice NAME or --specs FILE.jsonl")
        definition = get_slice(slice_name)
        if definition.union:
            raise SpecError(f"{slice_name} is the union of {', '.join(definition.parts)}: build each part")
        seed = definition.seed
        obstacles = definition.may_hold_obstacles
        specs_json = None
        total = selection.first_episodes(definition.episodes, slice_name)

    settings = dataclasses.replace(spec.settings, obstacle_clearance=obstacles)
    tasks = tuple(
        ShardTask(slice_name, first, end, None if specs_json is None else tuple(specs_json[first:end]))
        for first, end in shard_ranges(total, selection.shard_size)
    )
    storage.refuse_export("build")
    destination = storage.inside(slice_name)
    destination.refuse_export("build")
    job = Job(
        slice_name=slice_name,
        seed=seed,
        settings=settings.to_dict(),
        extra=extra,
        tasks=tasks,
        task_fn=build_shard,
        payload=settings,
        verb="built",
        key_prefix="shard",
        about="" if spec.execution.say is None else announcement(
            "building", slice_name, total, selection.shard_size, settings.resolution, counted=specs_json is None),
    )
    return run_job(job, spec.execution, destination)


def _load_user_specs(path: str, slice_name: str | None) -> list[EpisodeSpec]:
    """A specs file's episodes, numbered 0..n-1 in their own ``episode_index`` order, each
    checked feasible here (a refusal names the file and line, before any work starts)."""
    from pipeline.stages.episode import plan
    from schemas.spec import read_specs_lines

    lines = read_specs_lines(path)
    seen: dict[int, int] = {}
    for lineno, spec in lines:
        if spec.episode_index in seen:
            raise SpecError(
                f"{path}:{lineno}: episode_index {spec.episode_index} is a duplicate (line {seen[spec.episode_index]} has it)"
            )
        seen[spec.episode_index] = lineno
        try:
            plan(spec)
        except InfeasibleError as exc:
            raise SpecError(f"{path}:{lineno}: infeasible episode {spec.episode_id}: {exc}") from None
        except SpecError as exc:  # a motion whose tokens cannot be joined (a planar token after a flight)
            raise SpecError(f"{path}:{lineno}: episode {spec.episode_id}: {exc}") from None
    specs = [spec for _, spec in lines]
    names = sorted({s.slice for s in specs})
    if len(names) != 1:
        raise SpecError(f"{path}: all specs must share one slice name, got {names}")
    if slice_name is not None and names[0] != slice_name:
        raise SpecError(f"{path}: specs belong to slice {names[0]!r}, not --slice {slice_name!r}")
    specs = sorted(specs, key=lambda s: s.episode_index)
    indices = [s.episode_index for s in specs]
    if indices != list(range(len(specs))):
        bad = next(i for i, idx in enumerate(indices) if idx != i)
        raise SpecError(f"{path}: episode_index values must be 0..{len(specs) - 1} without gaps, found {indices[bad]!r}")
    return specs


__all__ = ["DEFAULT_SHARD_SIZE", "BuildSettings", "build", "build_job", "build_shard", "run_build"]
