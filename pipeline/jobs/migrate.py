"""`catalog migrate`: move a dataset 2.0.0 folder (all three files of a shard in ``shards/``)
into the table folders (``frames/``, ``episodes/``, ``mcap/``) without rewriting any file.

Paths are not part of the slice hash, so the folder keeps its hash and its dataset version
(its bytes are still 2.0.0's: it reads and scores, it is not rebuilt by this code). Files
move with ``os.replace`` one by one and ``catalog.json`` is rewritten last, atomically: a
migration killed halfway is finished by running it again, and a reader in between sees a
clear missing-file error, never a wrong table. A run of repeats (``repeats.json``)
migrates each repeat.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from catalog.manifest import Manifest, load_manifest, write_manifest
from catalog.records import TABLE_LAYOUT, FileRecord, ShardRecord, is_legacy, shard_paths
from pipeline.jobs.lock import folder_lock
from schemas.errors import ShardError


@dataclasses.dataclass(frozen=True)
class MigrationReport:
    """What one folder's migration did."""

    folder: str
    shards: int
    moved: int
    already: bool


def _move(root: Path, old: FileRecord, new_path: str) -> bool:
    """Move one file to its table folder; False when an interrupted migration already did."""
    source, target = root / old.path, root / new_path
    if source.is_file():
        if target.exists():
            raise ShardError(f"{target}: exists beside {source}; cannot tell which is the shard's (check both)")
        if source.stat().st_size != old.size:
            raise ShardError(f"{source}: {source.stat().st_size} bytes, catalog.json says {old.size} (run catalog verify)")
        target.parent.mkdir(exist_ok=True)
        os.replace(source, target)
        return True
    if target.is_file() and target.stat().st_size == old.size:
        return False
    raise ShardError(f"{source}: missing (neither there nor at {new_path})")


def _migrated_record(root: Path, shard: ShardRecord) -> tuple[ShardRecord, int]:
    paths = shard_paths(*shard.episodes, TABLE_LAYOUT)
    moved, files = 0, {}
    for kind, record in shard.files.items():
        moved += _move(root, record, paths[kind])
        files[kind] = FileRecord(paths[kind], record.sha256, record.size)
    return ShardRecord(shard.episodes, shard.frames, files), moved


def migrate_folder(directory: str | os.PathLike[str]) -> MigrationReport:
    """Migrate one slice or run folder (see the module docstring)."""
    root = Path(directory)
    if not root.is_dir():
        raise ShardError(f"{os.fspath(directory)}: no such folder")
    with folder_lock(root):
        manifest = load_manifest(root)
        if not any(is_legacy(shard) for shard in manifest.shards):
            return MigrationReport(os.fspath(root), len(manifest.shards), 0, True)
        moved, shards = 0, []
        for shard in manifest.shards:
            record, count = _migrated_record(root, shard) if is_legacy(shard) else (shard, 0)
            shards.append(record)
            moved += count
        migrated = Manifest(
            slice=manifest.slice, seed=manifest.seed, episodes=manifest.episodes, frames=manifest.frames,
            code=manifest.code, settings=manifest.settings, shards=tuple(shards), hash=manifest.hash,
            extra=manifest.extra, stats=manifest.stats,
        )
        write_manifest(root, migrated)
        legacy = root / "shards"
        if legacy.is_dir() and not any(legacy.iterdir()):
            legacy.rmdir()
    return MigrationReport(os.fspath(root), len(shards), moved, False)


def migrate(directory: str | os.PathLike[str]) -> list[MigrationReport]:
    """Migrate a folder, or each repeat of a run of repeats."""
    from pipeline.jobs.repeats import REPEATS_FILE, repeat_folders

    root = Path(directory)
    if (root / REPEATS_FILE).is_file():
        return [migrate_folder(folder) for folder in repeat_folders(root)]
    return [migrate_folder(root)]
