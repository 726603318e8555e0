"""The manifest's records of shards and their files, and the shard file names.

A shard covers episodes ``[first, end)`` of its slice and is stored as three files
under ``shards/`` (DESIGN.md, "Catalog manifest"), named by the first and the last
(inclusive) episode: ``000000-000127.frames.parquet``, ``.episodes.parquet``, ``.mcap``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import PurePosixPath
from types import MappingProxyType
from typing import Any

from catalog.hashing import FILE_KINDS, is_sha256
from schemas.errors import ShardError

SHARDS_DIR = "shards"
_SUFFIXES = {"frames": ".frames.parquet", "episodes": ".episodes.parquet", "mcap": ".mcap"}


def shard_stem(first: int, end: int) -> str:
    """``{first:06d}-{last:06d}`` for episodes ``[first, end)``."""
    if not (isinstance(first, int) and isinstance(end, int)) or first < 0 or end <= first:
        raise ShardError(f"a shard needs 0 <= first < end, got episodes [{first!r}, {end!r})")
    return f"{first:06d}-{end - 1:06d}"


def shard_paths(first: int, end: int) -> dict[str, str]:
    """Relative (POSIX) paths of the three files of the shard of episodes ``[first, end)``."""
    stem = shard_stem(first, end)
    return {kind: f"{SHARDS_DIR}/{stem}{_SUFFIXES[kind]}" for kind in FILE_KINDS}


def check_relative_path(path: Any, where: str) -> str:
    """A manifest path must be relative, POSIX, and stay inside the slice folder."""
    if not isinstance(path, str) or not path:
        raise ShardError(f"{where}: path must be a non-empty string, got {path!r}")
    pure = PurePosixPath(path)
    if pure.is_absolute() or "\\" in path or any(part in ("..", ".", "") for part in path.split("/")):
        raise ShardError(f"{where}: path must be relative inside the slice folder, got {path!r}")
    return path


@dataclass(frozen=True)
class FileRecord:
    """One file of a shard: path relative to the slice folder, sha256 and size in bytes."""

    path: str
    sha256: str
    size: int

    def __post_init__(self) -> None:
        check_relative_path(self.path, "file record")
        if not is_sha256(self.sha256):
            raise ShardError(f"{self.path}: sha256 must be 64 lower-case hex digits, got {self.sha256!r}")
        if isinstance(self.size, bool) or not isinstance(self.size, int) or self.size < 0:
            raise ShardError(f"{self.path}: size must be an integer >= 0, got {self.size!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"path": self.path, "sha256": self.sha256, "size": self.size}

    @classmethod
    def from_dict(cls, data: Any, where: str = "file record") -> FileRecord:
        if not isinstance(data, dict):
            raise ShardError(f"{where} must be an object, got {data!r}")
        missing = [k for k in ("path", "sha256", "size") if k not in data]
        if missing:
            raise ShardError(f"{where} is missing key(s) {missing}")
        return cls(data["path"], data["sha256"], data["size"])


@dataclass(frozen=True)
class ShardRecord:
    """A finished shard: its episode range ``[first, end)``, frame count and files by kind."""

    episodes: tuple[int, int]
    frames: int
    files: Mapping[str, FileRecord]

    def __post_init__(self) -> None:
        episodes = tuple(self.episodes)
        if len(episodes) != 2:
            raise ShardError(f"shard episodes must be [first, end), got {self.episodes!r}")
        shard_stem(*episodes)
        object.__setattr__(self, "episodes", episodes)
        if isinstance(self.frames, bool) or not isinstance(self.frames, int) or self.frames < episodes[1] - episodes[0]:
            raise ShardError(f"shard {episodes}: frames must be an integer >= its episode count, got {self.frames!r}")
        if set(self.files) != set(FILE_KINDS):
            raise ShardError(f"shard {episodes}: files must be exactly {list(FILE_KINDS)}, got {sorted(self.files)}")
        expected = shard_paths(*episodes)
        for kind in FILE_KINDS:
            record = self.files[kind]
            if not isinstance(record, FileRecord):
                raise ShardError(f"shard {episodes}: files[{kind!r}] must be a FileRecord, got {record!r}")
            if record.path != expected[kind]:
                raise ShardError(f"shard {episodes}: {kind} file must be {expected[kind]!r}, got {record.path!r}")
        object.__setattr__(self, "files", MappingProxyType({kind: self.files[kind] for kind in FILE_KINDS}))

    @property
    def first(self) -> int:
        return self.episodes[0]

    @property
    def end(self) -> int:
        return self.episodes[1]

    @property
    def num_episodes(self) -> int:
        return self.end - self.first

    def file_hashes(self) -> list[str]:
        """sha256 of the files in :data:`FILE_KINDS` order (the slice hash's order)."""
        return [self.files[kind].sha256 for kind in FILE_KINDS]

    def to_dict(self) -> dict[str, Any]:
        return {
            "episodes": list(self.episodes),
            "frames": self.frames,
            "files": {kind: self.files[kind].to_dict() for kind in FILE_KINDS},
        }

    @classmethod
    def from_dict(cls, data: Any, where: str = "shard") -> ShardRecord:
        if not isinstance(data, dict):
            raise ShardError(f"{where} must be an object, got {data!r}")
        missing = [k for k in ("episodes", "frames", "files") if k not in data]
        if missing:
            raise ShardError(f"{where} is missing key(s) {missing}")
        episodes, files = data["episodes"], data["files"]
        if not isinstance(episodes, list) or len(episodes) != 2 or not all(
            isinstance(v, int) and not isinstance(v, bool) for v in episodes
        ):
            raise ShardError(f"{where}.episodes must be [first, end) integers, got {episodes!r}")
        if not isinstance(files, dict):
            raise ShardError(f"{where}.files must be an object, got {files!r}")
        records = {kind: FileRecord.from_dict(value, f"{where}.files.{kind}") for kind, value in files.items()}
        return cls((episodes[0], episodes[1]), data["frames"], records)
