"""The integrity half of ``catalog verify``: every file a manifest lists is present,
has its recorded size and sha256, and opens as what it claims to be; no temp file
of an unfinished write and no unlisted file (of any name, hidden ones too) lies in a
data folder: the table folders and the folders of the audit files the manifest lists.

(The other half, rebuilding shards and comparing bytes, lives in the pipeline.)
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from catalog.store.atomic import find_stray_temps
from catalog.store.manifest import MANIFEST_NAME, Manifest, load_manifest
from catalog.store.records import SHARD_DIRS, FileRecord, ShardRecord
from catalog.store.storage import as_location, is_remote
from catalog.tables.mcap_reader import check_mcap
from catalog.tables.parquet_io import check_parquet, open_parquet, table_kind
from catalog.tables.reader import check_file, check_settings
from schemas.errors import (
    ShardError,
    ShardHashMismatch,
    ShardMissing,
    ShardSizeMismatch,
)
from schemas.names import shorten

#: Problem kinds, in the order a file is checked.
KINDS = ("missing", "size", "sha256", "unreadable", "stray-temp", "unlisted")


@dataclass(frozen=True)
class Problem:
    """One bad file: its path relative to the folder, what is wrong, and details."""

    path: str
    kind: str
    detail: str

    def __str__(self) -> str:
        return f"{self.path}: {self.detail}"


def _file_problem(root: Path, record: FileRecord) -> Problem | None:
    """A listed file that is missing, of another size or another sha256."""
    try:
        check_file(root, record, "sha256")
    except ShardError as exc:
        found = {ShardMissing: "missing", ShardSizeMismatch: "size", ShardHashMismatch: "sha256"}.get(type(exc), "unreadable")
        return Problem(record.path, found, str(exc).removeprefix(f"{root / record.path}: "))
    return None


def _check_file(root: Path, shard: ShardRecord, kind: str, full: bool) -> Problem | None:
    record = shard.files[kind]
    path = root / record.path
    problem = _file_problem(root, record)
    if problem is not None:
        return problem
    try:
        if kind == "frames":
            check_parquet(path, "frames", rows=shard.frames)
        elif kind == "episodes":
            with open_parquet(path) as parquet:
                found = table_kind(parquet)
            check_parquet(path, found if found != "frames" else "episodes", rows=shard.num_episodes)
        else:
            check_mcap(path, frames=shard.frames, full=full)
    except ShardError as exc:
        detail = str(exc)
        prefix = f"{path}: "
        return Problem(record.path, "unreadable", detail[len(prefix) :] if detail.startswith(prefix) else detail)
    return None


def check_files(
    directory: str | os.PathLike[str],
    manifest: Manifest,
    sample: int | None = None,
    rng: np.random.Generator | None = None,
    *,
    full: bool = False,
) -> list[Problem]:
    """Every problem found, shards in manifest order, then stray and unlisted files.

    ``sample`` checks only that many shards (all three files each), drawn without
    replacement by ``rng`` (default ``numpy.random.default_rng(0)``, a fixed choice).
    ``full`` also reads every MCAP chunk and checks its CRCs (the sha256 already
    covers every byte; this guards against a manifest written over bad files).
    """
    root = as_location(directory)
    shards = list(manifest.shards)
    if sample is not None:
        if isinstance(sample, bool) or not isinstance(sample, int) or sample < 1:
            raise ShardError(f"--sample must be an integer >= 1, got {shorten(repr(sample))}")
        if sample < len(shards):
            generator = np.random.default_rng(0) if rng is None else rng
            chosen = np.sort(generator.choice(len(shards), size=sample, replace=False))
            shards = [shards[i] for i in chosen]
    problems = []
    for shard in shards:
        for kind in shard.files:
            problem = _check_file(root, shard, kind, full)
            if problem is not None:
                problems.append(problem)
    for record in [*([] if manifest.stats is None else [manifest.stats]), *(manifest.audit or ())]:
        problem = _file_problem(root, record)
        if problem is not None:
            problems.append(problem)
    return problems + stray_files(root, manifest)


def data_folders(manifest: Manifest) -> list[str]:
    """The folders that hold only files the manifest lists: the table folders (both
    layouts) and the folders of its audit files."""
    audit = {record.path.rpartition("/")[0] for record in manifest.audit or ()}
    return sorted({*SHARD_DIRS, *(folder for folder in audit if folder)})


def stray_files(directory: str | os.PathLike[str], manifest: Manifest) -> list[Problem]:
    """Temporaries of unfinished writes anywhere in the folder, and anything in a data
    folder (:func:`data_folders`) that the manifest does not list, sorted by path."""
    root = as_location(directory)
    problems = []
    temps = set() if is_remote(root) else set(find_stray_temps(root))  # object stores have no temporaries
    for temp in sorted(temps):
        rel = temp.relative_to(root).as_posix()
        problems.append(Problem(rel, "stray-temp", "temporary file of an unfinished write (remove it or rebuild)"))
    listed = {path for path, _, _ in manifest.files()} | {record.path for record in manifest.audit or ()}
    for folder in data_folders(manifest):
        shard_dir = root / folder
        for path in sorted(shard_dir.iterdir()) if shard_dir.is_dir() else ():
            rel = path.relative_to(root).as_posix()
            if rel not in listed and path not in temps:
                problems.append(Problem(rel, "unlisted", f"not listed in {MANIFEST_NAME}"))
    return problems


def raise_first(directory: str | os.PathLike[str], problems: list[Problem]) -> None:
    """ShardError naming the first problem's file (and how many more there are), if any."""
    if problems:
        first = problems[0]
        more = f" (and {len(problems) - 1} more problem(s))" if len(problems) > 1 else ""
        where = str(directory).rstrip("/") + "/" + first.path
        raise ShardError(f"{where}: {first.detail}{more}")


def verify_files(
    directory: str | os.PathLike[str],
    sample: int | None = None,
    rng: np.random.Generator | None = None,
    *,
    full: bool = False,
) -> Manifest:
    """Load the manifest and check the files; ShardError naming the first bad file.

    The settings are checked first (:func:`catalog.tables.reader.check_settings`: SettingsMismatch
    naming ``catalog.json``), so a folder written with another fps is not rebuilt.
    Returns the manifest when everything is intact.
    """
    manifest = load_manifest(directory)
    check_settings(as_location(directory), manifest.settings)  # fps, image format: named in catalog.json
    raise_first(directory, check_files(directory, manifest, sample, rng, full=full))
    return manifest
