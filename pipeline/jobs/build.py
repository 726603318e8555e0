"""`pipeline build`: a slice's shards, resumable and byte-reproducible.

Each shard task (:func:`build_shard`) runs the episode stage, renders, JPEG-encodes and
writes Parquet + MCAP under temporary names, then renames, where the job's output is (a
folder, or uploaded to the object store from the worker: :mod:`pipeline.jobs.sink`). Everything around the shards
(the folder's one-job rule, resume, progress, Dask, statistics, the manifest) is
:func:`pipeline.jobs.runner.run_job`'s.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from catalog.manifest import Manifest
from catalog.stats import written_partial
from catalog.storage import as_location, is_url
from pipeline.jobs.engine import refuse_export_folder
from pipeline.jobs.object_store import run_job_at
from pipeline.jobs.runner import PARTIAL_STATS, Job, JobResult
from pipeline.jobs.sink import ShardSink
from pipeline.jobs.tasks import ShardTask, default_workers, shard_ranges
from schemas.errors import InfeasibleError, SpecError
from schemas.formats import ALL_FORMATS, parse_formats
from schemas.names import shorten
from schemas.renderers import DEFAULT_RENDERER, check_renderer, dataset_version_of, renderer_of
from schemas.spec import EpisodeSpec
from schemas.versions import DATASET_VERSION, FPS

DEFAULT_SHARD_SIZE = 128


@dataclass(frozen=True)
class BuildSettings:
    """Everything besides the specs that determines a shard's bytes."""

    resolution: int
    jpeg_quality: int
    fps: int = FPS
    image_format: str = "jpeg"
    #: Names the renderer too (:mod:`schemas.renderers`): 4.0.0 ``window``, 3.0.0 ``full``.
    dataset_version: str = DATASET_VERSION
    #: The frames table carries the hand's obstacle clearance (scenes may hold obstacles).
    obstacle_clearance: bool = False
    #: A rollout's evaluation protocol (pipeline.loop.conditions.EvalProtocol.to_dict), None
    #: for the plain closed loop and for builds.
    protocol: dict | None = None
    #: What is stored: Parquet always, MCAP (for viewing) unless left out.
    formats: tuple[str, ...] = ALL_FORMATS

    def __post_init__(self) -> None:
        object.__setattr__(self, "formats", parse_formats(self.formats))
        if not isinstance(self.resolution, int) or not 16 <= self.resolution <= 1024:
            raise SpecError(f"resolution must be an integer in [16, 1024], got {shorten(repr(self.resolution))}")
        if not isinstance(self.jpeg_quality, int) or not 1 <= self.jpeg_quality <= 100:
            raise SpecError(f"jpeg_quality must be an integer in [1, 100], got {shorten(repr(self.jpeg_quality))}")
        if renderer_of(self.dataset_version) is None:
            raise SpecError(f"dataset_version {self.dataset_version!r} is not one this code writes")

    @property
    def renderer(self) -> str:
        """The renderer that draws this dataset version's frames."""
        renderer = renderer_of(self.dataset_version)
        assert renderer is not None  # checked in __post_init__
        return renderer

    def as_dict(self) -> dict:
        """The manifest's settings; ``obstacle_clearance`` and ``protocol`` only when set, so
        builds without obstacles and plain runs keep the settings (and hashes) they always had."""
        out = asdict(self)
        if not self.obstacle_clearance:
            del out["obstacle_clearance"]
        if self.protocol is None:
            del out["protocol"]
        out["formats"] = list(self.formats)
        return out


def build_shard(task: ShardTask, settings: BuildSettings, sink: ShardSink) -> dict:
    """Worker side: write one shard where the job's output is; its record as a plain dict."""
    from pipeline.stages.record import write_ground_truth_shard

    with sink.writing() as folder:
        record = write_ground_truth_shard(task.specs(), task.first, task.end, settings, folder)
        partial = written_partial(folder, record)  # while the files are on this host
    return {"record": record.to_dict(), PARTIAL_STATS: partial}


def build(slice_name: str | None, out: Path, **options: Any) -> Manifest:
    """Build a slice (or a specs file) into ``out/<slice>/`` and return its manifest;
    the options are :func:`build_job`'s."""
    return build_job(slice_name, out, **options).manifest


def build_job(
    slice_name: str | None,
    out: Path,
    *,
    episodes: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    resolution: int = 224,
    shard_size: int = DEFAULT_SHARD_SIZE,
    specs_path: str | None = None,
    progress: bool = True,
    overwrite: bool = False,
    formats: str | tuple[str, ...] = ALL_FORMATS,
    renderer: str = DEFAULT_RENDERER,
) -> JobResult:
    """Build a slice (or a specs file) into ``out/<slice>/``: its manifest, and whether
    the folder already held this complete build (then nothing is redone).

    ``workers`` defaults to one per core (0: in this process, no Dask). A folder holding
    another build is refused unless ``overwrite``. ``renderer`` (:mod:`schemas.renderers`)
    decides the dataset version: ``window`` 4.0.0, ``full`` 3.0.0."""
    from generators.encode import JPEG_QUALITY

    version = dataset_version_of(check_renderer(renderer))
    as_location(out, "out")  # a folder name or URL, checked before anything is read

    extra: dict[str, str] = {}
    obstacles = False
    if specs_path is not None:
        specs = _load_user_specs(specs_path, slice_name)
        slice_name = specs[0].slice
        seed = specs[0].seed if len({s.seed for s in specs}) == 1 else None
        if episodes is not None:
            if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
                raise SpecError(f"--episodes must be >= 1, got {shorten(repr(episodes))}")
            specs = specs[:episodes]
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
        total = definition.episodes if episodes is None else episodes
        if isinstance(total, bool) or not isinstance(total, int) or not 1 <= total <= definition.episodes:
            raise SpecError(f"--episodes must be in [1, {definition.episodes}] for {slice_name}, got {shorten(repr(total))}")

    settings = BuildSettings(
        resolution=resolution, jpeg_quality=JPEG_QUALITY, obstacle_clearance=obstacles, formats=parse_formats(formats),
        dataset_version=version,
    )
    tasks = tuple(
        ShardTask(slice_name, first, end, None if specs_json is None else tuple(specs_json[first:end]))
        for first, end in shard_ranges(total, shard_size)
    )
    remote = is_url(out)
    if not remote:
        for folder in (Path(out), Path(out) / slice_name):
            refuse_export_folder(folder, "build")
    destination = f"{str(out).rstrip('/')}/{slice_name}" if remote else Path(out) / slice_name
    job = Job(
        folder=Path("/nonexistent-remote-job") if remote else Path(destination),
        slice_name=slice_name,
        seed=seed,
        settings=settings.as_dict(),
        extra=extra,
        tasks=tasks,
        task_fn=build_shard,
        payload=settings,
        verb="built",
        key_prefix="shard",
    )
    return run_job_at(
        job, destination, workers=default_workers() if workers is None else workers, scheduler=scheduler,
        progress=progress, overwrite=overwrite,
    )


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


__all__ = ["DEFAULT_SHARD_SIZE", "BuildSettings", "build", "build_job", "build_shard"]
