"""The shard files of a slice or run folder, for tests that compare folders byte for byte."""

from __future__ import annotations

from pathlib import Path

from catalog.store.records import shard_like_files


def shard_bytes(folder: Path) -> dict[str, bytes]:
    """``{relative path: bytes}`` of every shard file (frames/, episodes/, mcap/)."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in shard_like_files(Path(folder))}


def shard_names(folder: Path) -> list[str]:
    """Relative paths of the shard files in ``folder``, sorted."""
    return sorted(shard_bytes(folder))
