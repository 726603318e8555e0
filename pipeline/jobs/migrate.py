"""`catalog migrate`: bring a folder of a previous release up to this one's manifest:
move a dataset 2.0.0 folder (all three files of a shard in ``shards/``) into the table
folders (``frames/``, ``episodes/``, ``mcap/``) without rewriting any file, and seal a
manifest written before Dyana sealed every key (``key_sha256``, :mod:`catalog.store.manifest`).

Sealing comes after checking every file the manifest lists (size, sha256, readable) and
that no unlisted file lies in a data folder; a VLM run's ``vlm/index.json`` is checked
and moved into the manifest (``audit``). The keys outside the slice hash are sealed as
found: migrate a folder you trust (a hand edit made before migrating is not detectable).

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

from catalog.store.manifest import Manifest, load_manifest, manifest_path, write_manifest
from catalog.store.records import TABLE_LAYOUT, FileRecord, ShardRecord, is_legacy, shard_paths
from catalog.tables.integrity import check_files, raise_first
from pipeline.jobs.audit import LEGACY_INDEX, legacy_trail
from pipeline.jobs.lock import folder_lock
from pipeline.policy_registry import KINDS
from schemas.errors import ShardError


@dataclasses.dataclass(frozen=True)
class MigrationReport:
    """What one folder's migration did."""

    folder: str
    shards: int
    moved: int
    already: bool
    sealed: bool = False


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
        manifest = load_manifest(root, sealed=False)
        trail = _legacy_trail(root, manifest)
        current = manifest_path(root).read_text(encoding="utf-8") == manifest.to_json()
        if current and trail is None and not any(is_legacy(shard) for shard in manifest.shards):
            return MigrationReport(os.fspath(root), len(manifest.shards), 0, True)
        moved, shards = 0, []
        for shard in manifest.shards:
            record, count = _migrated_record(root, shard) if is_legacy(shard) else (shard, 0)
            shards.append(record)
            moved += count
        migrated = Manifest(
            slice=manifest.slice, seed=manifest.seed, episodes=manifest.episodes, frames=manifest.frames,
            code=manifest.code, settings=manifest.settings, shards=tuple(shards), hash=manifest.hash,
            extra=manifest.extra, stats=manifest.stats, audit=manifest.audit if trail is None else trail[1],
            versions=manifest.versions,
        )
        raise_first(root, [p for p in check_files(root, migrated) if trail is None or p.path != trail[0]])
        write_manifest(root, migrated)
        if trail is not None:
            (root / trail[0]).unlink(missing_ok=True)
        legacy = root / "shards"
        if legacy.is_dir() and not any(legacy.iterdir()):
            legacy.rmdir()
    return MigrationReport(os.fspath(root), len(shards), moved, False, sealed=not current)


def _legacy_trail(root: Path, manifest: Manifest) -> tuple[str, tuple[FileRecord, ...]] | None:
    """A previous release's audit index (path) and the trail records it vouches for, for a
    run of an audited kind whose manifest lists no trail yet; None otherwise."""
    for kind in KINDS:
        if kind.manifest_key in manifest.extra and kind.audit_dir is not None:
            index = f"{kind.audit_dir}/{LEGACY_INDEX}"
            if manifest.audit is not None:
                return (index, manifest.audit) if (root / index).is_file() else None
            records = legacy_trail(root, kind.audit_dir)
            if records is None:
                raise ShardError(f"{root / kind.audit_dir}: a {kind.name} run without {LEGACY_INDEX}: its trail cannot be checked")
            return index, tuple(records)
    return None


def migrate(directory: str | os.PathLike[str]) -> list[MigrationReport]:
    """Migrate a folder, or each repeat of a run of repeats."""
    from pipeline.jobs.repeats import REPEATS_FILE, repeat_folders

    root = Path(directory)
    if (root / REPEATS_FILE).is_file():
        return [migrate_folder(folder) for folder in repeat_folders(root)]
    return [migrate_folder(root)]
