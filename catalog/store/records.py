"""The manifest's records of shards and their files, and the shard file names.

A shard covers episodes ``[first, end)`` of its slice. Each table has a folder of its own
(the data contract, ``docs/concepts/data-contract.md``), so any Parquet reader opens ``frames/`` or ``episodes/``
as one dataset; a shard's files are named by its first and last (inclusive) episode:
``frames/000000-000127.parquet``, ``episodes/000000-000127.parquet`` and (unless the build
left MCAP out) ``mcap/000000-000127.mcap``.

Datasets before 3.0.0 kept all three in ``shards/`` (``shards/000000-000127.frames.parquet``,
``.episodes.parquet``, ``.mcap``): their records still load (:data:`LEGACY_LAYOUT`), and
``catalog migrate`` moves such a folder into the table folders.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from types import MappingProxyType
from typing import Any

from catalog.store.hashing import FILE_KINDS, is_sha256
from schemas.errors import ShardError
from schemas.names import shorten

#: The tables every shard has; ``mcap`` is optional (``--formats parquet``).
REQUIRED_KINDS = ("frames", "episodes")
#: Folder and suffix of each kind of file, by layout.
TABLE_LAYOUT = {"frames": ("frames", ".parquet"), "episodes": ("episodes", ".parquet"), "mcap": ("mcap", ".mcap")}
LEGACY_LAYOUT = {
    "frames": ("shards", ".frames.parquet"),
    "episodes": ("shards", ".episodes.parquet"),
    "mcap": ("shards", ".mcap"),
}
#: Every folder a slice's shard files can live in (current and legacy layouts).
SHARD_DIRS = tuple(sorted({folder for folder, _ in (*TABLE_LAYOUT.values(), *LEGACY_LAYOUT.values())}))


def shard_stem(first: int, end: int) -> str:
    """``{first:06d}-{last:06d}`` for episodes ``[first, end)``."""
    if not (isinstance(first, int) and isinstance(end, int)) or first < 0 or end <= first:
        raise ShardError(f"a shard needs 0 <= first < end, got episodes [{first!r}, {end!r})")
    return f"{first:06d}-{end - 1:06d}"


def shard_paths(first: int, end: int, layout: Mapping[str, tuple[str, str]] = TABLE_LAYOUT) -> dict[str, str]:
    """Relative (POSIX) paths of the files of the shard of episodes ``[first, end)``."""
    stem = shard_stem(first, end)
    return {kind: f"{folder}/{stem}{suffix}" for kind, (folder, suffix) in layout.items()}


_SHARD_NAME = re.compile(r"\d{6}-\d{6}(\.frames\.parquet|\.episodes\.parquet|\.parquet|\.mcap)")


def shard_like_files(root: Path) -> list[Path]:
    """Files in ``root``'s shard folders named like shard files (of either layout), sorted."""
    found: list[Path] = []
    for folder in SHARD_DIRS:
        directory = root / folder
        if directory.is_dir():
            found.extend(p for p in directory.iterdir() if _SHARD_NAME.fullmatch(p.name) and p.is_file())
    return sorted(found)


def is_legacy(record: ShardRecord) -> bool:
    """True for a shard stored in the pre-3.0.0 ``shards/`` layout."""
    return record.files["frames"].path == shard_paths(*record.episodes, LEGACY_LAYOUT)["frames"]


def check_relative_path(path: Any, where: str) -> str:
    """A manifest path must be relative, POSIX, and stay inside the slice folder."""
    if not isinstance(path, str) or not path:
        raise ShardError(f"{where}: path must be a non-empty string, got {shorten(repr(path))}")
    pure = PurePosixPath(path)
    if pure.is_absolute() or "\\" in path or any(part in ("..", ".", "") for part in path.split("/")):
        raise ShardError(f"{where}: path must be relative inside the slice folder, got {shorten(repr(path))}")
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
            raise ShardError(f"{self.path}: size must be an integer >= 0, got {shorten(repr(self.size))}")

    def to_dict(self) -> dict[str, Any]:
        return {"path": self.path, "sha256": self.sha256, "size": self.size}

    @classmethod
    def from_dict(cls, data: Any, where: str = "file record") -> FileRecord:
        if not isinstance(data, dict):
            raise ShardError(f"{where} must be an object, got {shorten(repr(data))}")
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
            raise ShardError(f"shard episodes must be [first, end), got {shorten(repr(self.episodes))}")
        shard_stem(*episodes)
        object.__setattr__(self, "episodes", episodes)
        if isinstance(self.frames, bool) or not isinstance(self.frames, int) or self.frames < episodes[1] - episodes[0]:
            raise ShardError(f"shard {episodes}: frames must be an integer >= its episode count, got {shorten(repr(self.frames))}")
        kinds = set(self.files)
        if not set(REQUIRED_KINDS) <= kinds <= set(FILE_KINDS):
            raise ShardError(
                f"shard {episodes}: files must be {list(REQUIRED_KINDS)} and optionally 'mcap', got {sorted(self.files)}"
            )
        for kind in self.files:
            if not isinstance(self.files[kind], FileRecord):
                raise ShardError(f"shard {episodes}: files[{kind!r}] must be a FileRecord, got {self.files[kind]!r}")
        layout = LEGACY_LAYOUT if self.files["frames"].path == shard_paths(*episodes, LEGACY_LAYOUT)["frames"] else TABLE_LAYOUT
        expected = shard_paths(*episodes, layout)
        for kind in self.files:
            if self.files[kind].path != expected[kind]:
                raise ShardError(
                    f"shard {episodes}: {kind} file must be {expected[kind]!r}, got {self.files[kind].path!r}"
                )
        ordered = {kind: self.files[kind] for kind in FILE_KINDS if kind in self.files}
        object.__setattr__(self, "files", MappingProxyType(ordered))

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
        return [record.sha256 for record in self.files.values()]

    def to_dict(self) -> dict[str, Any]:
        return {
            "episodes": list(self.episodes),
            "frames": self.frames,
            "files": {kind: record.to_dict() for kind, record in self.files.items()},
        }

    @classmethod
    def from_dict(cls, data: Any, where: str = "shard") -> ShardRecord:
        if not isinstance(data, dict):
            raise ShardError(f"{where} must be an object, got {shorten(repr(data))}")
        missing = [k for k in ("episodes", "frames", "files") if k not in data]
        if missing:
            raise ShardError(f"{where} is missing key(s) {missing}")
        episodes, files = data["episodes"], data["files"]
        if not isinstance(episodes, list) or len(episodes) != 2 or not all(
            isinstance(v, int) and not isinstance(v, bool) for v in episodes
        ):
            raise ShardError(f"{where}.episodes must be [first, end) integers, got {shorten(repr(episodes))}")
        if not isinstance(files, dict):
            raise ShardError(f"{where}.files must be an object, got {shorten(repr(files))}")
        records = {kind: FileRecord.from_dict(value, f"{where}.files.{kind}") for kind, value in files.items()}
        return cls((episodes[0], episodes[1]), data["frames"], records)
