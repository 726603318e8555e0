"""A policy kind's audit trail (:class:`pipeline.policy_registry.Audited`, e.g. a VLM's
exchanges): one JSON-lines file per shard in the run's trail folder, and an index of
their hashes that replay checks before it re-runs the policy from the records."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from catalog.atomic import atomic_write_text
from catalog.hashing import sha256_file
from schemas.errors import ShardError


def audit_path(folder: Path, first: int, end: int) -> Path:
    """The trail file of shard ``[first, end)``."""
    return folder / f"audit-{first:06d}-{end:06d}.jsonl"


def write_audit(folder: Path, first: int, end: int, records: list[dict[str, Any]]) -> None:
    """A shard's records, one JSON object per line, written whole or not at all."""
    text = "".join(json.dumps(r, sort_keys=True, allow_nan=False) + "\n" for r in records)
    path = audit_path(folder, first, end)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)


def read_audit(folder: Path) -> list[dict[str, Any]]:
    """Every record of a trail, in shard order."""
    records: list[dict[str, Any]] = []
    for path in sorted(Path(folder).glob("audit-*.jsonl")):
        records += [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line]
    return records


def write_audit_index(folder: Path) -> None:
    """``index.json``: every trail file with its sha256 and size (what replay checks)."""
    files = {p.name: {"sha256": sha256_file(p), "size": p.stat().st_size} for p in sorted(folder.glob("audit-*.jsonl"))}
    atomic_write_text(folder / "index.json", json.dumps({"files": files}, indent=2, sort_keys=True) + "\n")


def check_audit_index(folder: Path) -> None:
    """Refuse a trail whose files are missing, extra or changed since the run."""
    folder = Path(folder)
    index = folder / "index.json"
    if not index.is_file():
        raise ShardError(f"{index}: missing (the run's audit trail has no index)")
    files = json.loads(index.read_text())["files"]
    present = sorted(p.name for p in folder.glob("audit-*.jsonl"))
    if present != sorted(files):
        raise ShardError(f"{index}: lists {sorted(files)} but the folder holds {present}")
    for name, record in files.items():
        path = folder / name
        if path.stat().st_size != record["size"] or sha256_file(path) != record["sha256"]:
            raise ShardError(f"{path}: changed since the run (sha256 differs from {index.name})")
