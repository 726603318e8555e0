"""A policy kind's audit trail (:class:`pipeline.policy_registry.Audited`, e.g. a VLM's
exchanges): one JSON-lines file per shard in the run's trail folder, each listed with its
sha256 and size in the run's sealed ``catalog.json`` (key ``audit``), so the model's
answers, which replay cannot re-derive, cannot change unseen.

Runs of the previous release kept that listing in ``<trail>/index.json`` instead;
``catalog migrate`` checks it and moves it into the manifest (:func:`legacy_trail`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from catalog.store.atomic import atomic_write_text
from catalog.store.hashing import sha256_file
from catalog.store.manifest import Manifest
from catalog.store.records import FileRecord
from schemas.errors import ShardError

#: The previous release's listing of a trail's files.
LEGACY_INDEX = "index.json"


def stamped(records: Sequence[dict[str, Any]], episode_id: str) -> list[dict[str, Any]]:
    """An episode's records with its id, added on Dyana's side: the policy that made them
    was never told which episode it played."""
    return [{**record, "episode_id": episode_id} for record in records]


def audit_path(folder: Path, first: int, end: int) -> Path:
    """The trail file of shard ``[first, end)``."""
    return folder / f"audit-{first:06d}-{end:06d}.jsonl"


def write_audit(folder: Path, first: int, end: int, records: list[dict[str, Any]]) -> None:
    """A shard's records, one JSON object per line, written whole or not at all."""
    text = "".join(json.dumps(r, sort_keys=True, allow_nan=False) + "\n" for r in records)
    path = audit_path(folder, first, end)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)


def audit_records(root: Path, audit_dir: str, ranges: Sequence[tuple[int, int]]) -> list[FileRecord]:
    """The manifest's records (path, sha256, size) of the trail files of the shards ``ranges``."""
    records = []
    for first, end in ranges:
        path = audit_path(root / audit_dir, first, end)
        if not path.is_file():
            raise ShardError(f"{path}: missing (shard [{first}, {end}) wrote no audit trail)")
        records.append(FileRecord(path.relative_to(root).as_posix(), sha256_file(path), path.stat().st_size))
    return records


def remove_unlisted_audit(root: Path, audit_dir: str, manifest: Manifest) -> None:
    """Delete trail files ``manifest`` does not list (of a job it replaced) and a previous
    release's index."""
    listed = {record.path for record in manifest.audit or ()}
    folder = root / audit_dir
    for path in sorted(folder.glob("audit-*.jsonl")) + [folder / LEGACY_INDEX]:
        if path.is_file() and path.relative_to(root).as_posix() not in listed:
            path.unlink()


def read_audit(root: Path, records: Sequence[FileRecord] | None = None) -> list[dict[str, Any]]:
    """Every record of the trail files ``records`` (the manifest's ``audit``, paths relative
    to ``root``), in order; without ``records``, of every trail file in the folder ``root``."""
    out: list[dict[str, Any]] = []
    paths = sorted(Path(root).glob("audit-*.jsonl")) if records is None else [Path(root) / r.path for r in records]
    for path in paths:
        try:
            out += [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line]
        except (OSError, ValueError) as exc:
            raise ShardError(f"{path}: unreadable audit trail ({type(exc).__name__})") from None
    return out


def legacy_trail(root: Path, audit_dir: str) -> list[FileRecord] | None:
    """The records of a previous release's trail, from its ``index.json`` once every file
    it lists is there unchanged and no other lies beside them (None without an index)."""
    folder = root / audit_dir
    index = folder / LEGACY_INDEX
    if not index.is_file():
        return None
    try:
        files = json.loads(index.read_text(encoding="utf-8"))["files"]
        listed = {str(name): (str(entry["sha256"]), int(entry["size"])) for name, entry in files.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ShardError(f"{index}: unreadable index of the audit trail ({type(exc).__name__})") from None
    present = sorted(p.name for p in folder.glob("audit-*.jsonl"))
    if present != sorted(listed):
        raise ShardError(f"{index}: lists {sorted(listed)} but the folder holds {present}")
    records = []
    for name in present:
        path = folder / name
        sha256, size = listed[name]
        if path.stat().st_size != size or sha256_file(path) != sha256:
            raise ShardError(f"{path}: changed since the run (sha256 differs from {LEGACY_INDEX})")
        records.append(FileRecord(path.relative_to(root).as_posix(), sha256, size))
    return records
