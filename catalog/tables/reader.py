"""One way to read a built slice or a rollout folder, with one set of checks.

Every consumer (the dataloader, scoring, statistics, view, replay, verify) opens a
folder with :func:`open_folder` and reads its shards through :class:`ShardReader`, so
the same things are checked everywhere, once per shard, with the same typed errors
(:mod:`schemas.errors`):

- the manifest loads and its hash matches (:func:`catalog.store.manifest.load_manifest`);
- the settings are ones this code reads: the dataset version, fps and image format it
  writes (:class:`~schemas.errors.SettingsMismatch`), and whatever the caller expects;
- every listed file is on disk with its recorded size (:class:`~schemas.errors.ShardMissing`,
  :class:`~schemas.errors.ShardSizeMismatch`) and, with ``verify="sha256"``, its recorded
  content (:class:`~schemas.errors.ShardHashMismatch`);
- an episodes table holds exactly the shard's episodes in order
  (:class:`~schemas.errors.DuplicateEpisode`, :class:`~schemas.errors.ShardContentError`);
- a frames table has the manifest's row count, rows grouped by episode in order, each
  episode numbered 0..n-1 (:class:`~schemas.errors.FrameNumberingError`), only episodes of
  the shard, and each ground-truth episode as many frames as its row says.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from catalog.store.hashing import sha256_file
from catalog.store.manifest import Manifest, load_manifest
from catalog.store.records import FileRecord, ShardRecord
from catalog.store.storage import as_location, reaching
from catalog.tables.parquet_io import (
    column_to_numpy,
    open_parquet,
    read_episodes,
    read_frames,
    table_kind,
)
from schemas.errors import (
    DuplicateEpisode,
    FrameNumberingError,
    SettingsMismatch,
    ShardContentError,
    ShardError,
    ShardHashMismatch,
    ShardMissing,
    ShardSizeMismatch,
    SpecError,
)
from schemas.names import shorten
from schemas.runs import is_run
from schemas.versions import FPS, READABLE_DATASET_VERSIONS

VERIFY_MODES = ("size", "sha256")
#: Settings every reader relies on, with the values this code writes.
REQUIRED_SETTINGS = {"fps": FPS, "image_format": "jpeg"}


def check_verify(verify: object) -> None:
    """SpecError (a ValueError too) unless ``verify`` is one of :data:`VERIFY_MODES`."""
    if not isinstance(verify, str) or verify not in VERIFY_MODES:
        raise SpecError(f"verify must be one of {list(VERIFY_MODES)}, got {shorten(repr(verify))}")


def check_file(root: Path, record: FileRecord, verify: str = "size") -> Path:
    """The file's path once it exists with its recorded size (and sha256 with ``verify="sha256"``)."""
    check_verify(verify)
    path = root / record.path
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise ShardMissing(path) from None
    except OSError as exc:
        raise ShardError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if size != record.size:
        raise ShardSizeMismatch(path, record.size, size)
    if verify == "sha256":
        try:
            digest = sha256_file(path)
        except OSError as exc:
            raise ShardError(f"{path}: cannot read: {exc.strerror or exc}") from None
        if digest != record.sha256:
            raise ShardHashMismatch(path, record.sha256, digest)
    return path


def check_settings(root: Path, settings: Mapping[str, Any], expect: Mapping[str, Any] | None = None) -> None:
    """SettingsMismatch unless ``settings`` carry what readers rely on (and ``expect``)."""
    where = root / "catalog.json"
    version = settings.get("dataset_version")
    if version not in READABLE_DATASET_VERSIONS and "dataset_version" not in (expect or {}):
        raise SettingsMismatch(where, "dataset_version", f"one of {list(READABLE_DATASET_VERSIONS)}", version)
    for key, wanted in {**REQUIRED_SETTINGS, **(expect or {})}.items():
        if settings.get(key) != wanted:
            raise SettingsMismatch(where, key, wanted, settings.get(key))
    resolution = settings.get("resolution")
    if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 1:
        raise SettingsMismatch(where, "resolution", "a positive integer", resolution)


def frame_runs(path: Path, episode: np.ndarray, frame: np.ndarray, first: int, end: int) -> dict[int, tuple[int, int]]:
    """{episode_index: (first row, frames)} of a frames table, checking that each episode's
    rows are contiguous, in order, numbered 0..n-1, and within [first, end)."""
    n = len(episode)
    if n == 0:
        return {}
    if np.any(np.diff(episode) < 0):
        raise FrameNumberingError(path, "rows are not sorted by episode_index")
    starts = np.concatenate([[0], np.flatnonzero(np.diff(episode)) + 1])
    counts = np.diff(np.append(starts, n))
    expected = np.arange(n) - np.repeat(starts, counts)
    if not np.array_equal(frame, expected):
        bad = int(np.flatnonzero(frame != expected)[0])
        raise FrameNumberingError(
            path,
            f"row {bad} of episode {int(episode[bad])} has frame_index {int(frame[bad])}, expected {int(expected[bad])} "
            "(frames of an episode must be numbered 0..n-1 in order, each once)",
        )
    ids = episode[starts]
    if ids[0] < first or ids[-1] >= end:
        outside = int(ids[0] if ids[0] < first else ids[-1])
        raise ShardContentError(path, f"episode_index {outside} lies outside the shard's episodes [{first}, {end})")
    return {int(e): (int(s), int(c)) for e, s, c in zip(ids, starts, counts)}


@dataclass(frozen=True)
class ShardReader:
    """One shard of an opened folder: its checked tables."""

    root: Path
    record: ShardRecord
    rollout: bool
    verify: str

    def path(self, kind: str) -> Path:
        return self.root / self.record.files[kind].path

    def check_files(self, kinds: Sequence[str] | None = None) -> None:
        """Check the shard's files of ``kinds`` (default: every file it has)."""
        for kind in self.record.files if kinds is None else kinds:
            check_file(self.root, self.record.files[kind], self.verify)

    def episodes(self, columns: Sequence[str] | None = None) -> pa.Table:
        """The episodes table (``columns``, plus ``episode_index``), exactly the shard's episodes in order."""
        path = check_file(self.root, self.record.files["episodes"], self.verify)
        wanted = None if columns is None else list(dict.fromkeys(["episode_index", *columns]))
        table = read_episodes(path, wanted)
        index = table.column("episode_index").to_numpy()
        first, end = self.record.episodes
        repeated = np.flatnonzero(np.diff(np.sort(index)) == 0)
        if len(repeated):
            raise DuplicateEpisode(path, int(np.sort(index)[repeated[0]]))
        if not np.array_equal(index, np.arange(first, end)):
            raise ShardContentError(
                path, f"episode_index must be {first}..{end - 1} in order, got {index[:5].tolist()}{'...' * (len(index) > 5)}"
            )
        return table

    def frames(self, columns: Sequence[str] | None = None, episodes: pa.Table | None = None) -> pa.Table:
        """The frames table (``columns``, plus ``episode_index`` and ``frame_index``), checked
        against the manifest's row count and the frame numbering; with the shard's
        ``episodes`` table (``num_frames`` column), ground-truth frame counts too."""
        return self.indexed_frames(columns, episodes)[0]

    def indexed_frames(
        self, columns: Sequence[str] | None = None, episodes: pa.Table | None = None
    ) -> tuple[pa.Table, dict[int, tuple[int, int]]]:
        """:meth:`frames` and its episodes' runs ``{episode_index: (first row, frames)}``."""
        path = check_file(self.root, self.record.files["frames"], self.verify)
        wanted = None if columns is None else list(dict.fromkeys(["episode_index", "frame_index", *columns]))
        table = read_frames(path, wanted)
        if table.num_rows != self.record.frames:
            raise ShardContentError(path, f"has {table.num_rows} rows, catalog.json says {self.record.frames}")
        runs = frame_runs(
            path,
            column_to_numpy(table.column("episode_index")),
            column_to_numpy(table.column("frame_index")),
            *self.record.episodes,
        )
        if episodes is not None and not self.rollout and "num_frames" in episodes.column_names:
            for index, declared in zip(
                episodes.column("episode_index").to_pylist(), episodes.column("num_frames").to_pylist()
            ):
                count = runs.get(index, (0, 0))[1]
                if count != declared:
                    raise ShardContentError(path, f"episode {index} has {count} frames, its episodes row says {declared}")
        return table, runs


@dataclass(frozen=True)
class FolderReader:
    """An opened slice or rollout folder: its manifest and its shards."""

    root: Path
    manifest: Manifest
    rollout: bool
    shards: tuple[ShardReader, ...]

    def __iter__(self) -> Iterator[ShardReader]:
        return iter(self.shards)

    def shard_of(self, episode: int) -> ShardReader:
        for shard in self.shards:
            if shard.record.first <= episode < shard.record.end:
                return shard
        raise ShardError(f"{self.root}: no episode {episode} (it holds episodes [0, {self.manifest.episodes}))")

    def episodes(self, columns: Sequence[str] | None = None) -> pa.Table:
        return pa.concat_tables([s.episodes(columns) for s in self.shards])

    def frames(self, columns: Sequence[str] | None = None) -> pa.Table:
        return pa.concat_tables([s.frames(columns) for s in self.shards])

    def episode(self, index: int) -> tuple[dict[str, Any], pa.Table]:
        """One episode's row (as a dict) and its frames (every column)."""
        shard = self.shard_of(index)
        episodes = shard.episodes()
        frames = shard.frames(None, episodes)
        row = episodes.filter(pa.array(episodes.column("episode_index").to_numpy() == index)).to_pylist()[0]
        mine = frames.filter(pa.array(column_to_numpy(frames.column("episode_index")) == index))
        if mine.num_rows == 0:
            raise ShardContentError(shard.path("frames"), f"episode {index} has no frames")
        return row, mine


def open_folder(
    directory: str | os.PathLike[str], *, verify: str = "size", expect: Mapping[str, Any] | None = None
) -> FolderReader:
    """Open a built slice or a rollout folder: manifest, settings and shard kinds checked;
    each table is checked as it is read (sizes always, sha256 with ``verify="sha256"``)."""
    check_verify(verify)
    root = as_location(directory, "directory")
    with reaching(root):  # an object store's failure: one StorageError naming the URL
        return _open_folder(root, directory, verify, expect)


def _open_folder(root: Path, directory: object, verify: str, expect: Mapping[str, Any] | None) -> FolderReader:
    if not root.is_dir():
        raise ShardError(f"{directory}: no such folder (expected a built slice or run holding catalog.json)")
    manifest = load_manifest(root)
    check_settings(root, manifest.settings, expect)
    rollout = is_run(manifest.extra)
    shards = []
    for record in manifest.shards:
        path = check_file(root, record.files["episodes"], "size")
        with open_parquet(path) as parquet:
            kind = table_kind(parquet)
        if (kind == "rollout_episodes") != rollout:
            what = "rollout" if kind == "rollout_episodes" else "ground-truth"
            raise ShardContentError(
                path, f"is a {what} episodes table but catalog.json describes {'rollouts' if rollout else 'a built slice'}"
            )
        shards.append(ShardReader(root, record, rollout, verify))
    return FolderReader(root, manifest, rollout, tuple(shards))
