"""`pipeline build`: a slice's shards as Dask tasks, resumable, byte-reproducible.

Each task builds one whole shard (a fixed range of episodes): episode stage, render,
JPEG encode, write Parquet + MCAP under temporary names, rename. The driver records
every finished shard in ``.build-state.json`` (atomically), so a killed build resumes:
shards whose files still match their recorded sha256 are skipped. ``catalog.json`` is
written last, then ``stats.json`` (normalisation statistics of states and actions,
computed without decoding images). The manifest's hash covers the settings and the
ordered file hashes only, so the worker count, the scheduler and interruptions cannot
change it.
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from catalog.atomic import atomic_write_text, remove_stray_temps
from catalog.hashing import sha256_file
from catalog.stats import load_stats
from catalog.manifest import Manifest, ShardRecord, compute_hash, git_commit, write_manifest
from schemas.errors import DyanaError, ShardError, SpecError
from schemas.spec import EpisodeSpec
from schemas.versions import CODE_VERSION, DATASET_VERSION, FPS

STATE_FILE = ".build-state.json"
DEFAULT_SHARD_SIZE = 128


@dataclass(frozen=True)
class BuildSettings:
    """Everything besides the specs that determines a shard's bytes."""

    resolution: int
    jpeg_quality: int
    fps: int = FPS
    image_format: str = "jpeg"
    dataset_version: str = DATASET_VERSION

    def __post_init__(self) -> None:
        if not isinstance(self.resolution, int) or not 16 <= self.resolution <= 1024:
            raise SpecError(f"resolution must be an integer in [16, 1024], got {self.resolution!r}")
        if not isinstance(self.jpeg_quality, int) or not 1 <= self.jpeg_quality <= 100:
            raise SpecError(f"jpeg_quality must be an integer in [1, 100], got {self.jpeg_quality!r}")

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ShardTask:
    """One shard: episodes [first, end) of ``slice_name``, from the recipe or from given specs."""

    slice_name: str
    first: int
    end: int
    specs_json: tuple[str, ...] | None = None

    def specs(self) -> list[EpisodeSpec]:
        if self.specs_json is not None:
            return [EpisodeSpec.from_json(text) for text in self.specs_json]
        from generators.recipe import spec_for

        return [spec_for(self.slice_name, i) for i in range(self.first, self.end)]


def shard_ranges(episodes: int, shard_size: int) -> list[tuple[int, int]]:
    """Fixed episode ranges [first, end) of at most ``shard_size`` episodes."""
    if shard_size < 1:
        raise SpecError(f"--shard-size must be >= 1, got {shard_size!r}")
    return [(a, min(a + shard_size, episodes)) for a in range(0, episodes, shard_size)]


def build_shard(task: ShardTask, settings: BuildSettings, slice_dir: str) -> dict:
    """Worker side: write one shard and return its record as a plain dict."""
    from pipeline.record import write_ground_truth_shard

    record = write_ground_truth_shard(task.specs(), task.first, task.end, settings, Path(slice_dir))
    return record.to_dict()


def _load_state(
    slice_dir: Path, settings: BuildSettings, commit: str | None, source: str
) -> dict[tuple[int, int], ShardRecord]:
    """Shards a previous run of the same build (same settings, code and episode source)
    finished whose files are intact."""
    path = slice_dir / STATE_FILE
    if not path.exists():
        return {}
    try:
        state = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ShardError(f"{path}: unreadable build state ({exc}); remove it to rebuild from scratch") from exc
    if state.get("settings") != settings.as_dict() or state.get("commit") != commit or state.get("source") != source:
        return {}
    done: dict[tuple[int, int], ShardRecord] = {}
    for raw in state.get("shards", []):
        record = ShardRecord.from_dict(raw)
        intact = all(
            (slice_dir / f.path).is_file() and sha256_file(slice_dir / f.path) == f.sha256 for f in record.files.values()
        )
        if intact:
            done[tuple(record.episodes)] = record
    return done


def _save_state(slice_dir: Path, settings: BuildSettings, commit: str | None, source: str, done: dict) -> None:
    state = {
        "settings": settings.as_dict(),
        "commit": commit,
        "source": source,
        "shards": [done[key].to_dict() for key in sorted(done)],
    }
    atomic_write_text(slice_dir / STATE_FILE, json.dumps(state, sort_keys=True, indent=2) + "\n")


class Progress:
    """One line per finished shard on stderr: shards, frames, frames/s, ETA."""

    def __init__(self, total_shards: int, total_episodes: int, stream=sys.stderr) -> None:
        self.total_shards = total_shards
        self.total_episodes = total_episodes
        self.stream = stream
        self.start = time.monotonic()
        self.shards = 0
        self.episodes = 0
        self.frames = 0

    def update(self, record: ShardRecord, skipped: bool = False) -> None:
        self.shards += 1
        self.episodes += record.episodes[1] - record.episodes[0]
        if skipped:
            return
        self.frames += record.frames
        elapsed = max(time.monotonic() - self.start, 1e-9)
        rate = self.frames / elapsed
        left = self.total_episodes - self.episodes
        eta = left * (self.frames / max(self.episodes, 1)) / max(rate, 1e-9)
        print(
            f"[{self.shards}/{self.total_shards} shards] {self.episodes}/{self.total_episodes} episodes, "
            f"{self.frames} frames, {rate:.1f} frames/s, {self.shards / elapsed * 60:.1f} shards/min, "
            f"eta {eta:.0f}s",
            file=self.stream,
            flush=True,
        )


#: Worker settings for CPU-bound whole-shard tasks: no statistical profiler sampling the
#: task thread every 10 ms, no work stealing of long tasks, no spilling (results are tiny).
LEAN_WORKERS = {
    "distributed.worker.profile.enabled": False,
    "distributed.scheduler.work-stealing": False,
    "distributed.worker.memory.spill": False,
    "distributed.worker.memory.target": False,
}


def run_tasks(
    tasks: Sequence[ShardTask],
    settings: BuildSettings,
    slice_dir: Path,
    workers: int,
    scheduler: str | None,
    on_done: Callable[[Any], None],
    task_fn: Callable[[ShardTask, Any, str], Any] | None = None,
    key_prefix: str = "shard",
) -> None:
    """Run shard tasks on a local cluster (one single-threaded process per worker) or
    on an existing scheduler; call ``on_done`` in the driver as each shard finishes.

    By default each task is :func:`build_shard` and ``on_done`` receives its
    ShardRecord; with ``task_fn`` (``pipeline eval`` passes its rollout shard function)
    each task is ``task_fn(task, settings, str(slice_dir))`` and ``on_done`` receives
    its result as returned."""
    if not tasks:
        return
    import dask
    from dask.distributed import Client, LocalCluster, as_completed

    if not scheduler and workers < 1:
        raise SpecError(f"--workers must be >= 1, got {workers!r}")
    with dask.config.set(LEAN_WORKERS):
        cluster = None
        if scheduler:
            try:
                client = Client(scheduler, timeout="30s")
            except (OSError, ValueError, TypeError) as exc:  # unreachable, timed out, or not an address
                raise DyanaError(f"--scheduler {scheduler!r}: cannot connect to the Dask scheduler: {exc}") from None
        else:
            cluster = LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40
            )
            try:
                client = Client(cluster)
            except BaseException:
                cluster.close()
                raise
        try:
            futures = [
                client.submit(
                    build_shard if task_fn is None else task_fn,
                    task,
                    settings,
                    str(slice_dir),
                    key=f"{key_prefix}-{task.first:06d}-{task.end:06d}",
                    pure=False,
                )
                for task in tasks
            ]
            for future in as_completed(futures):
                result = future.result()
                on_done(ShardRecord.from_dict(result) if task_fn is None else result)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


_SHARD_FILE = re.compile(r"\d{6}-\d{6}\.(frames\.parquet|episodes\.parquet|mcap)")


def remove_unlisted_shards(slice_dir: Path, manifest: Manifest) -> list[Path]:
    """Delete shard files in ``slice_dir/shards`` that ``manifest`` does not list: the
    leftovers of an earlier build of the folder with another ``--episodes`` or
    ``--shard-size``, which would otherwise fail ``catalog verify`` and be picked up
    by ``shards/*.parquet`` globs. Only files named like shards are touched."""
    listed = {path for path, _, _ in manifest.files()}
    removed = []
    shard_dir = slice_dir / "shards"
    for path in sorted(shard_dir.iterdir()) if shard_dir.is_dir() else []:
        if _SHARD_FILE.fullmatch(path.name) and f"shards/{path.name}" not in listed and path.is_file():
            path.unlink()
            removed.append(path)
    return removed


def build(
    slice_name: str | None,
    out: Path,
    *,
    episodes: int | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    resolution: int = 224,
    shard_size: int = DEFAULT_SHARD_SIZE,
    specs_path: str | None = None,
    progress: bool = True,
) -> Manifest:
    """Build a slice (or a specs file) into ``out/<slice>/`` and return its manifest."""
    from generators.encode import JPEG_QUALITY

    settings = BuildSettings(resolution=resolution, jpeg_quality=JPEG_QUALITY)
    specs_json: list[str] | None = None
    if specs_path is not None:
        specs = _load_user_specs(specs_path, slice_name)
        slice_name = specs[0].slice
        seed = specs[0].seed if len({s.seed for s in specs}) == 1 else None
        if episodes is not None:
            specs = specs[:episodes]
        specs_json = [s.to_json() for s in specs]
        total = len(specs)
    else:
        from schemas.slices import get_slice

        if slice_name is None:
            raise SpecError("give --slice NAME or --specs FILE.jsonl")
        definition = get_slice(slice_name)
        if definition.union:
            raise SpecError(f"{slice_name} is the union of {', '.join(definition.parts)}: build each part")
        seed = definition.seed
        total = definition.episodes if episodes is None else episodes
        if not 1 <= total <= definition.episodes:
            raise SpecError(f"--episodes must be in [1, {definition.episodes}] for {slice_name}, got {total!r}")

    slice_dir = out / slice_name
    (slice_dir / "shards").mkdir(parents=True, exist_ok=True)
    remove_stray_temps(slice_dir)
    commit = git_commit()
    if specs_json is None:
        source = f"recipe:{slice_name}:{seed}"
    else:
        source = "specs:" + hashlib.sha256("\n".join(specs_json).encode()).hexdigest()
    done = _load_state(slice_dir, settings, commit, source)
    tasks = []
    for first, end in shard_ranges(total, shard_size):
        if (first, end) in done:
            continue
        chunk = tuple(specs_json[first:end]) if specs_json is not None else None
        tasks.append(ShardTask(slice_name, first, end, chunk))

    ranges = shard_ranges(total, shard_size)
    meter = Progress(len(ranges), total) if progress else None
    if meter is not None and done:
        print(f"resuming: {len(done)} of {len(ranges)} shards already built", file=sys.stderr)
        for key in sorted(done):
            if key in dict.fromkeys(ranges):
                meter.update(done[key], skipped=True)

    def on_done(record: ShardRecord) -> None:
        done[tuple(record.episodes)] = record
        _save_state(slice_dir, settings, commit, source, done)
        if meter is not None:
            meter.update(record)

    run_tasks(tasks, settings, slice_dir, workers, scheduler, on_done)

    shards = [done[key] for key in ranges]
    manifest = Manifest(
        slice=slice_name,
        seed=seed,
        episodes=total,
        frames=sum(s.frames for s in shards),
        code={"version": CODE_VERSION, "commit": commit},
        settings=settings.as_dict(),
        shards=shards,
        hash=compute_hash(settings.as_dict(), shards),
    )
    write_manifest(slice_dir, manifest)
    remove_unlisted_shards(slice_dir, manifest)
    load_stats(slice_dir, manifest)
    (slice_dir / STATE_FILE).unlink(missing_ok=True)
    return manifest


def _load_user_specs(path: str, slice_name: str | None) -> list[EpisodeSpec]:
    """A specs file's episodes, numbered 0..n-1 in their own ``episode_index`` order."""
    from schemas.spec import read_specs_jsonl

    specs = read_specs_jsonl(path)
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


__all__ = ["BuildSettings", "ShardTask", "build", "shard_ranges", "DyanaError"]
