"""`catalog verify`: every listed file intact, and sampled shards rebuilt byte for byte.

Integrity (sha256, sizes, readable Parquet/MCAP, no stray temps) comes from
``catalog.integrity``. Rebuilding re-runs the episode stage, the renderer and the writers
on the specs stored in each shard's episodes table (so slices built from a user's
``--specs`` file verify too) into a temporary folder, and compares the bytes.
Rollout sets are re-executed through ``pipeline.jobs.replay`` instead.

Progress (with ``on_shard``, or ``progress=True``): a line per rebuilt episode on stderr,
at most one per 2 s plus the last (:class:`schemas.cli.ProgressMeter`).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from catalog.integrity import verify_files
from catalog.manifest import Manifest
from catalog.parquet_io import read_episodes
from catalog.records import ShardRecord
from catalog.storage import as_location
from pipeline.jobs.runner import ReportingSpecs, reporting_episodes
from schemas.cli import ProgressMeter
from schemas.errors import ShardError
from schemas.spec import EpisodeSpec
from schemas.versions import DATASET_VERSION


@dataclass(frozen=True)
class VerifyReport:
    slice: str
    shards_checked: int
    shards_rebuilt: int
    files_compared: int


def _sample_shards(manifest: Manifest, sample: int | None, rng: np.random.Generator) -> list[ShardRecord]:
    shards = list(manifest.shards)
    if sample is None or sample >= len(shards):
        return shards
    picks = rng.choice(len(shards), size=sample, replace=False)
    return [shards[i] for i in sorted(picks)]


def _stored_specs(directory: Path, shard: ShardRecord) -> list[EpisodeSpec]:
    path = directory / shard.files["episodes"].path
    table = read_episodes(path, columns=["episode_index", "spec"])
    return [EpisodeSpec.from_json(text) for text in table.column("spec").to_pylist()]


def check_rebuildable(directory: Path, manifest: Manifest) -> None:
    """ShardError unless this code writes ``manifest``'s dataset version (rebuilds and replays
    compare bytes, so an older version's folder can be read and scored but not re-executed)."""
    built_with = manifest.settings.get("dataset_version")
    if built_with != DATASET_VERSION:
        raise ShardError(
            f"{directory}/catalog.json: written as dataset version {built_with!r}; this code writes "
            f"{DATASET_VERSION!r}, so its shards cannot be re-executed byte for byte (check out the commit "
            f"{manifest.code.commit or 'that wrote it'})"
        )


def rebuild_shard(directory: Path, manifest: Manifest, shard: ShardRecord, scratch: Path) -> int:
    """Rebuild one ground-truth shard into ``scratch`` and compare its files' bytes."""
    from pipeline.jobs.build import BuildSettings
    from pipeline.stages.record import write_ground_truth_shard

    check_rebuildable(directory, manifest)
    known = {f.name for f in fields(BuildSettings)}
    unknown = sorted(set(manifest.settings) - known)
    if unknown:
        raise ShardError(f"{directory / 'catalog.json'}: unknown settings {unknown}: written by another version of Dyana?")
    settings = BuildSettings(**manifest.settings)
    specs = ReportingSpecs(_stored_specs(directory, shard), shard.first, shard.end)  # episode progress
    rebuilt = write_ground_truth_shard(specs, shard.first, shard.end, settings, scratch)
    for kind, record in shard.files.items():
        again = rebuilt.files[kind]
        if again.sha256 != record.sha256:
            raise ShardError(
                f"{directory / record.path}: rebuilding gives different bytes "
                f"(sha256 {again.sha256[:12]}… instead of {record.sha256[:12]}…)"
            )
    return len(shard.files)


def verify(
    directory: str | Path,
    sample: int | None = None,
    rng: np.random.Generator | None = None,
    on_shard: Callable[[ShardRecord], None] | None = None,
    progress: bool | None = None,
) -> VerifyReport:
    """Check every file, then rebuild ``sample`` shards (all by default) and compare bytes.

    ``progress`` (default: whether ``on_shard`` is given) prints episode progress lines of
    the rebuild on stderr."""
    directory = as_location(directory)
    rng = np.random.default_rng(0) if rng is None else rng
    manifest = verify_files(directory)
    shards = _sample_shards(manifest, sample, rng)
    if "policy" in manifest.extra:
        from pipeline.jobs.replay import replay

        replay(directory, shards=[s.first for s in shards])
        return VerifyReport(manifest.slice, len(manifest.shards), len(shards), 0)
    compared = 0
    show = on_shard is not None if progress is None else progress
    meter = ProgressMeter(sum(s.end - s.first for s in shards)) if show else None
    finished = [0, 0]  # episodes, frames of the shards rebuilt

    def report(first: int, end: int, done: int, frames: int) -> None:
        if meter is not None and done < end - first:  # a shard's last episode is counted when it is compared
            meter.update(finished[0] + done, finished[1] + frames, prefix=f"[rebuilding {first}-{end - 1}]")

    with tempfile.TemporaryDirectory(prefix="dyana-verify-") as scratch, reporting_episodes(report):
        for shard in shards:
            compared += rebuild_shard(directory, manifest, shard, Path(scratch))
            finished[0] += shard.end - shard.first
            finished[1] += shard.frames
            if meter is not None:
                meter.update(finished[0], finished[1], prefix=f"[{shards.index(shard) + 1}/{len(shards)} shards rebuilt]")
            if on_shard is not None:
                on_shard(shard)
    return VerifyReport(manifest.slice, len(manifest.shards), len(shards), compared)
