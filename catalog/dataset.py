"""The researchers' dataloader: ``catalog.open(path)`` over built slices or rollouts.

``catalog.open(path, history=0, action_horizon=None, ...)`` returns a
:class:`FrameDataset`, a sequence of frames. ``ds[i]`` is a dict:

=====================  =====================================  ==================================
key                    history=0                              history=K (K >= 1)
=====================  =====================================  ==================================
``image``              (H, W, 3) uint8 RGB                    (K+1, H, W, 3), current frame last
``<state>``            (width,) float32 for each of            (K+1, width) float32
                       object_pose, object_velocity,
                       palm_pose, joint_angles,
                       joint_poses, keypoints
``fingertip_distance`` float32 scalar                         (K+1,) float32
``<key>_is_pad``       absent                                 (K+1,) bool for image and each state
``action``             (18,) float32                          same (see ``action_horizon``)
``phase``              str                                    str (current frame)
``episode_index``      int64 scalar                           same
``frame_index``        int32 scalar                           same (current frame)
``timestamp``          float64 scalar (as stored)             same (current frame)
``text``               str, the episode's instruction         same
``source``             int, the folder's position (only       same
                       when several folders are opened)
=====================  =====================================  ==================================

``action_horizon=None`` (the default) gives the current action, shape (18,).
``action_horizon=H`` (an integer >= 1) gives ``action`` of shape (H, 18), the actions
of the current frame and the H - 1 after it, and ``action_is_pad`` (H,). Windows are
integer frame arithmetic within one episode (``catalog.windows``): padded slots
repeat the episode's first (history) or last (horizon) frame and are flagged.

Reading. Opening reads the manifests, the episodes tables and the ``episode_index``
and ``frame_index`` columns of every frames file, to build the index (position ->
episode -> shard row) from integer frame numbers. Files are opened lazily, in each
process separately (a DataLoader worker never inherits a parent's file handles or
caches). The first use of a shard in a process loads its float columns as one
float32 matrix and walks the image column's pages for each JPEG's byte offset
(``catalog.pages``); a frame is then one ``os.pread`` of its JPEG and one decode.
Loaded shards stay in a per-process LRU cache bounded by ``cache_mb`` (the float
columns are about 0.7 KB a frame; image bytes are never cached), so memory stays
flat over any number of passes. Random access runs at decoding speed while the
selected frames' shards fit the cache; for bigger selections use
:meth:`FrameDataset.iterable`, which loads each shard once per epoch.

Corrupt data (guarantees). At open, every frames and episodes file must exist with
the size ``catalog.json`` records (a truncated or extended file raises ShardError
naming it) and the episodes tables are read with their page checksums verified. On
a shard's first use in a process, ``verify="sha256"`` (the default) hashes the
frames file and compares it with ``catalog.json`` (episodes files are hashed at
open): any changed byte is caught. ``verify="checksums"`` skips the hash; every page
read is then CRC32-checked (pyarrow's page checksum verification for the float
columns, Dyana's own for the image pages, whose layout is also checked value by
value), which catches truncation and accidental corruption but not a deliberate
edit that rewrites the checksums too. Either way the file's ``episode_index`` and
``frame_index`` must still be what the index was built from, and a JPEG that does
not decode raises. A failed check raises ShardError naming the file, and no item of
that shard is returned. Limit: a process checks a file when it loads it; a file
rewritten in place while loaded is not checked again until it is reloaded.
"""

from __future__ import annotations

import hashlib
import io
import os
import sys
from bisect import bisect_right
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from catalog.hashing import sha256_file
from catalog.manifest import Manifest, load_manifest
from catalog.pages import image_offsets
from catalog.parquet_io import check_columns, column_to_numpy, open_parquet, read_episodes, read_frames, table_kind
from catalog.windows import episode_starts, history_window, horizon_window
from schemas.errors import ShardError, SpecError
from schemas.objects import OBJECTS
from schemas.scene import INTERCEPT_SECONDS, MOTION_TYPES, PHASES
from schemas.tables import ARRAY_WIDTHS, STATE_COLUMNS

VERIFY_MODES = ("sha256", "checksums")
#: Float columns of an item, in frames-table order; a shard keeps them side by side in one
#: float32 matrix (``fingertip_distance``, a scalar, takes one column).
FLOAT_COLUMNS = (*STATE_COLUMNS, "action", "fingertip_distance")


def _float_layout() -> dict[str, tuple[int, int]]:
    layout, start = {}, 0
    for name in FLOAT_COLUMNS:
        width = ARRAY_WIDTHS.get(name, 1)
        layout[name] = (start, start + width)
        start += width
    return layout


_LAYOUT = _float_layout()
FLOAT_WIDTH = _LAYOUT[FLOAT_COLUMNS[-1]][1]
_STATE_SLICES = tuple((name, slice(*_LAYOUT[name])) for name in STATE_COLUMNS)
_ACTION = slice(*_LAYOUT["action"])
_DISTANCE = _LAYOUT["fingertip_distance"][0]
_SHARD_COLUMNS = ("episode_index", "frame_index", "timestamp", "phase", *FLOAT_COLUMNS)
_EPISODE_COLUMNS = (
    "episode_index", "episode_id", "slice", "motion_type", "object", "hand",
    "rollout_format", "intercept_setting", "num_frames", "text",
)
_IMREAD = getattr(cv2, "IMREAD_COLOR_RGB", None)
_getpid = os.getpid


@dataclass(frozen=True)
class Episode:
    """One episode of an opened dataset, from its folder's episodes table.

    ``num_frames`` is the number of frames stored (an evaluated rollout holds as many
    as its policy ran, not its spec's ``num_frames``); ``policy`` and ``status`` are set
    for rollouts only; ``source`` is the folder's position in the opened list.
    """

    source: int
    episode_index: int
    episode_id: str
    slice: str
    motion_type: str
    intercept_setting: str
    object: str
    hand: str
    rollout_format: str
    num_frames: int
    text: str
    policy: str | None = None
    status: str | None = None


@dataclass(frozen=True)
class _ShardFile:
    """A frames file as the index knows it: where, how big, its digests."""

    path: str
    size: int
    sha256: str
    frames: int
    index_digest: str  # sha256 of its episode_index + frame_index columns, as read at open


@dataclass(frozen=True)
class _Options:
    history: int
    action_horizon: int | None
    resize: tuple[int, int] | None
    verify: str
    cache_bytes: int


def _index_digest(episode: np.ndarray, frame: np.ndarray) -> str:
    digest = hashlib.sha256(np.ascontiguousarray(episode, dtype=np.int64).tobytes())
    digest.update(np.ascontiguousarray(frame, dtype=np.int32).tobytes())
    return digest.hexdigest()


def _check_size(path: Path, size: int) -> None:
    try:
        found = path.stat().st_size
    except FileNotFoundError:
        raise ShardError(f"{path}: file is missing") from None
    except OSError as exc:
        raise ShardError(f"{path}: cannot read: {exc}") from None
    if found != size:
        state = "truncated" if found < size else "longer than recorded"
        raise ShardError(f"{path}: {state}: {found} bytes, catalog.json says {size}")


def _frame_runs(path: Path, episode: np.ndarray, frame: np.ndarray, first: int, end: int) -> dict[int, tuple[int, int]]:
    """{episode_index: (first row, frames)} of a frames file, checking that each
    episode's rows are contiguous, in order, and numbered 0..n-1."""
    n = len(episode)
    if n == 0:
        return {}
    if np.any(np.diff(episode) < 0):
        raise ShardError(f"{path}: rows are not sorted by episode_index")
    starts = np.concatenate([[0], np.flatnonzero(np.diff(episode)) + 1])
    counts = np.diff(np.append(starts, n))
    expected = np.arange(n) - np.repeat(starts, counts)
    if not np.array_equal(frame, expected):
        bad = int(np.flatnonzero(frame != expected)[0])
        raise ShardError(
            f"{path}: row {bad} has frame_index {int(frame[bad])}, expected {int(expected[bad])} "
            "(frames of an episode must be numbered 0..n-1 in order)"
        )
    ids = episode[starts]
    if ids[0] < first or ids[-1] >= end:
        raise ShardError(f"{path}: holds episodes outside its range [{first}, {end})")
    return {int(e): (int(s), int(c)) for e, s, c in zip(ids, starts, counts)}


def _load_source(root: Path, source: int, verify: str, files: list[_ShardFile]):
    """Episodes and spans (shard key, first row, frames) of one folder; appends its frames files to ``files``."""
    manifest = load_manifest(root)
    episodes: list[Episode] = []
    spans: list[tuple[int, int, int]] = []
    for shard in manifest.shards:
        frames_record, episodes_record = shard.files["frames"], shard.files["episodes"]
        frames_path, episodes_path = root / frames_record.path, root / episodes_record.path
        _check_size(frames_path, frames_record.size)
        _check_size(episodes_path, episodes_record.size)
        if verify == "sha256":
            digest = sha256_file(episodes_path)
            if digest != episodes_record.sha256:
                raise ShardError(
                    f"{episodes_path}: content changed: sha256 {digest}, catalog.json says {episodes_record.sha256}"
                )
        with open_parquet(episodes_path) as parquet:
            rollout = table_kind(parquet) == "rollout_episodes"
        columns = list(_EPISODE_COLUMNS) + (["policy", "status"] if rollout else [])
        table = read_episodes(episodes_path, columns).to_pydict()
        if table["episode_index"] != list(range(shard.first, shard.end)):
            raise ShardError(
                f"{episodes_path}: episode_index must be {shard.first}..{shard.end - 1} in order, "
                f"got {table['episode_index'][:5]}..."
            )
        index = read_frames(frames_path, ["episode_index", "frame_index"])
        if index.num_rows != shard.frames:
            raise ShardError(f"{frames_path}: has {index.num_rows} rows, catalog.json says {shard.frames}")
        episode = column_to_numpy(index.column("episode_index"))
        frame = column_to_numpy(index.column("frame_index"))
        runs = _frame_runs(frames_path, episode, frame, shard.first, shard.end)
        key = len(files)
        files.append(
            _ShardFile(
                str(frames_path), frames_record.size, frames_record.sha256, shard.frames, _index_digest(episode, frame)
            )
        )
        for row, episode_index in enumerate(table["episode_index"]):
            start, count = runs.get(episode_index, (0, 0))
            declared = table["num_frames"][row]
            if not rollout and count != declared:  # a rollout runs as long as its policy did
                raise ShardError(
                    f"{frames_path}: episode {episode_index} has {count} frames, its episodes row says {declared}"
                )
            values = {name: table[name][row] for name in columns}
            values["num_frames"] = count
            episodes.append(Episode(source=source, **values))
            spans.append((key, start, count))
    return manifest, episodes, spans


# --- per-process shard cache ----------------------------------------------------------


class _Descriptor:
    """Owns an open file descriptor and closes it when the last reference goes, so a
    shard evicted from the cache while an item is still being read from it keeps a
    valid descriptor (a closed number could be reused by another file)."""

    __slots__ = ("fd",)

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def __del__(self) -> None:
        try:
            os.close(self.fd)
        except Exception:  # already closed, or interpreter shutdown
            pass


class _OpenShard:
    """A frames file in use: its descriptor, float columns, timestamps, phases and JPEG offsets."""

    __slots__ = ("path", "owner", "fd", "floats", "timestamp", "phase", "offsets", "lengths", "nbytes")

    def __init__(self, path, owner, floats, timestamp, phase, offsets, lengths) -> None:
        self.path, self.owner, self.fd = path, owner, owner.fd
        self.floats, self.timestamp, self.phase = floats, timestamp, phase
        self.offsets, self.lengths = offsets, lengths
        # Python int lists (faster to index than numpy): about 72 bytes a row for the two.
        self.nbytes = floats.nbytes + timestamp.nbytes + phase.nbytes + 72 * len(offsets)

    def jpeg(self, row: int) -> bytes:
        length = self.lengths[row]
        data = os.pread(self.fd, length, self.offsets[row])
        if len(data) != length:
            raise ShardError(f"{self.path}: image of row {row} is cut off (file truncated while open)")
        return data


def _parquet_file(handle: io.FileIO, path: str, checksums: bool) -> pq.ParquetFile:
    """The Parquet reader of an open file (the very file that was hashed, even if the path
    has since been replaced), verifying page checksums if asked."""
    try:
        return pq.ParquetFile(handle, page_checksum_verification=checksums)
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise ShardError(f"{path}: not a readable Parquet file (truncated or corrupt): {exc}") from None


class _Reader:
    """The shards one process has open, in an LRU bounded by bytes (and by open files)."""

    MAX_OPEN = 128

    def __init__(self, files: Sequence[_ShardFile], verify: str, budget: int) -> None:
        self.pid = os.getpid()
        self.files = files
        self.verify = verify
        self.budget = budget
        self.cache: OrderedDict[int, _OpenShard] = OrderedDict()
        self.bytes = 0
        self.verified: set[int] = set()
        self.last: tuple[int, _OpenShard | None] = (-1, None)  # one tuple: swapped atomically between threads

    def get(self, key: int) -> _OpenShard:
        last_key, last = self.last
        if key == last_key:
            return last
        shard = self.cache.get(key)
        if shard is None:
            shard = self._load(key)
            self.cache[key] = shard
            self.bytes += shard.nbytes
            while len(self.cache) > 1 and (self.bytes > self.budget or len(self.cache) > self.MAX_OPEN):
                _, old = self.cache.popitem(last=False)
                self.bytes -= old.nbytes
        else:
            self.cache.move_to_end(key)
        self.last = (key, shard)
        return shard

    def _load(self, key: int) -> _OpenShard:
        record = self.files[key]
        path = record.path
        try:
            owner = _Descriptor(os.open(path, os.O_RDONLY))
        except FileNotFoundError:
            raise ShardError(f"{path}: file is missing") from None
        except OSError as exc:
            raise ShardError(f"{path}: cannot open: {exc}") from None
        fd = owner.fd
        size = os.fstat(fd).st_size
        if size != record.size:
            state = "truncated" if size < record.size else "longer than recorded"
            raise ShardError(f"{path}: {state}: {size} bytes, catalog.json says {record.size}")
        hashed = self.verify == "sha256" and key not in self.verified
        hasher = hashlib.sha256() if hashed else None
        # Right after hashing every byte, page checksums are redundant; otherwise they are checked.
        with io.FileIO(os.dup(fd), "r") as handle, _parquet_file(handle, path, checksums=not hashed) as parquet:
            offsets, lengths = image_offsets(fd, path, parquet.metadata, check_crc=not hashed, hasher=hasher, size=size)
            if hasher is not None:
                digest = hasher.hexdigest()
                if digest != record.sha256:
                    raise ShardError(f"{path}: content changed: sha256 {digest}, catalog.json says {record.sha256}")
                self.verified.add(key)
            if table_kind(parquet) != "frames":
                raise ShardError(f"{path}: not a frames table")
            check_columns(path, parquet, "frames", _SHARD_COLUMNS)
            if parquet.metadata.num_rows != record.frames:
                raise ShardError(f"{path}: has {parquet.metadata.num_rows} rows, catalog.json says {record.frames}")
            try:
                table = parquet.read(columns=list(_SHARD_COLUMNS), use_threads=False)
            except (pa.ArrowException, OSError, ValueError) as exc:
                raise ShardError(f"{path}: corrupt Parquet data: {exc}") from None
        episode = column_to_numpy(table.column("episode_index"))
        frame = column_to_numpy(table.column("frame_index"))
        if _index_digest(episode, frame) != record.index_digest:
            raise ShardError(f"{path}: episode_index/frame_index changed since the dataset was opened")
        for name in _SHARD_COLUMNS:
            if table.column(name).null_count:
                raise ShardError(f"{path}: column {name!r} holds null values (the contract has none)")
        n = table.num_rows
        floats = np.empty((n, FLOAT_WIDTH), dtype=np.float32)
        for name in FLOAT_COLUMNS:
            start, stop = _LAYOUT[name]
            floats[:, start:stop] = column_to_numpy(table.column(name)).reshape(n, stop - start)
        codes = pc.index_in(table.column("phase"), value_set=pa.array(PHASES))
        if codes.null_count:
            raise ShardError(f"{path}: phase holds a value outside {list(PHASES)}")
        phase = column_to_numpy(codes).astype(np.int8)
        timestamp = np.ascontiguousarray(column_to_numpy(table.column("timestamp")), dtype=np.float64)
        return _OpenShard(path, owner, floats, timestamp, phase, offsets, lengths)

    def close(self) -> None:
        """Forget every loaded shard (descriptors close as soon as no item is being read from them)."""
        self.cache.clear()
        self.bytes = 0
        self.last = (-1, None)


# --- the dataset ------------------------------------------------------------------------


def _choices(name: str, value: Any, allowed: Iterable[str]) -> frozenset[str] | None:
    if value is None:
        return None
    values = {value} if isinstance(value, str) else set(value)
    allowed = set(allowed)
    unknown = sorted(v for v in values if v not in allowed)
    if unknown:
        raise SpecError(f"{name} {unknown} unknown (expected some of {sorted(allowed)})")
    return frozenset(values)


def _episode_set(value: Any) -> frozenset[int] | range | None:
    if value is None:
        return None
    if isinstance(value, range):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return frozenset([int(value)])
    values = set()
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise SpecError(f"episodes must be integers (or a range), got {v!r}")
        values.add(int(v))
    return frozenset(values)


def _resize(value: Any) -> tuple[int, int] | None:
    if value is None:
        return None
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        value = (int(value), int(value))
    try:
        height, width = (int(v) for v in value)
    except (TypeError, ValueError):
        raise SpecError(f"resize must be a size or (height, width), got {value!r}") from None
    if height < 1 or width < 1:
        raise SpecError(f"resize must be positive, got {value!r}")
    return height, width


def _non_negative(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise SpecError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


class FrameDataset:
    """A sequence of frames over one or more folders; see the module docstring for items.

    Build one with :func:`open_dataset` (``catalog.open``). Safe to pass to
    ``torch.utils.data.DataLoader(num_workers>0)`` (directly or via :meth:`torch`):
    files are opened lazily in each process.
    """

    def __init__(self, roots, manifests, files, episodes, spans, options, reader=None, stats=None) -> None:
        self._roots: tuple[Path, ...] = tuple(roots)
        self._manifests: tuple[Manifest, ...] = tuple(manifests)
        self._files: tuple[_ShardFile, ...] = tuple(files)
        self._episodes: tuple[Episode, ...] = tuple(episodes)
        self._spans: tuple[tuple[int, int, int], ...] = tuple(spans)
        self._options: _Options = options
        self._starts = episode_starts([n for _, _, n in self._spans])
        self._len = sum(n for _, _, n in self._spans)
        self._reader: _Reader | None = reader
        self._stats = stats
        self._several = len(self._roots) > 1
        self._texts = [e.text for e in self._episodes]
        self._indices = [np.int64(e.episode_index) for e in self._episodes]

    # --- sizes and metadata -----------------------------------------------------------

    def __len__(self) -> int:
        return self._len

    @property
    def episodes(self) -> tuple[Episode, ...]:
        """The selected episodes, by folder then episode_index (empty ones included)."""
        return self._episodes

    @property
    def sources(self) -> tuple[Path, ...]:
        return self._roots

    @property
    def manifests(self) -> tuple[Manifest, ...]:
        return self._manifests

    @property
    def history(self) -> int:
        return self._options.history

    @property
    def action_horizon(self) -> int | None:
        return self._options.action_horizon

    def episode_frames(self, k: int) -> range:
        """Positions in this dataset of the frames of ``episodes[k]``."""
        start = self._starts[k]
        return range(start, start + self._spans[k][2])

    def episode(self, k: int) -> "FrameDataset":
        """The frames of ``episodes[k]`` alone (same options), as a dataset."""
        if not -len(self._episodes) <= k < len(self._episodes):
            raise IndexError(f"episode {k} is out of range for {len(self._episodes)} episodes")
        k %= len(self._episodes)
        return self._view([k])

    def select(
        self,
        *,
        motion_type: str | Iterable[str] | None = None,
        intercept_setting: str | Iterable[str] | None = None,
        object: str | Iterable[str] | None = None,
        episodes: range | Iterable[int] | int | None = None,
        where: Callable[[Episode], bool] | None = None,
    ) -> "FrameDataset":
        """The episodes matching every given filter (values may be one or several; ``episodes``
        filters on ``episode_index``, e.g. ``range(0, 100)``; ``where`` is any predicate)."""
        motions = _choices("motion_type", motion_type, (*MOTION_TYPES, "custom"))
        settings = _choices("intercept_setting", intercept_setting, INTERCEPT_SECONDS)
        objects = _choices("object", object, OBJECTS)
        indices = _episode_set(episodes)
        keep = []
        for k, e in enumerate(self._episodes):
            if motions is not None and e.motion_type not in motions:
                continue
            if settings is not None and e.intercept_setting not in settings:
                continue
            if objects is not None and e.object not in objects:
                continue
            if indices is not None and e.episode_index not in indices:
                continue
            if where is not None and not where(e):
                continue
            keep.append(k)
        return self._view(keep)

    def _view(self, keep: Sequence[int]) -> "FrameDataset":
        return FrameDataset(
            self._roots,
            self._manifests,
            self._files,
            [self._episodes[k] for k in keep],
            [self._spans[k] for k in keep],
            self._options,
            reader=self._reader,
            stats=self._stats,
        )

    @property
    def stats(self):
        """Normalisation statistics of the opened folders (all their frames, whatever the filters):
        ``ds.stats["action"].mean`` etc. (``catalog.stats``); read from or written to ``stats.json``."""
        if self._stats is None:
            from catalog.stats import combine, load_stats

            verify = self._options.verify == "sha256"
            self._stats = combine([load_stats(r, m, verify=verify) for r, m in zip(self._roots, self._manifests)])
        return self._stats

    # --- items -----------------------------------------------------------------------------

    def _new_reader(self) -> _Reader:
        self._reader = _Reader(self._files, self._options.verify, self._options.cache_bytes)
        return self._reader

    def _shard(self, key: int) -> _OpenShard:
        reader = self._reader
        if reader is None or reader.pid != _getpid():
            reader = self._new_reader()
        return reader.get(key)

    def _decode(self, shard: _OpenShard, row: int) -> np.ndarray:
        buffer = np.frombuffer(shard.jpeg(row), dtype=np.uint8)
        if _IMREAD is not None:
            image = cv2.imdecode(buffer, _IMREAD)
        else:
            image = cv2.imdecode(buffer, cv2.IMREAD_COLOR)
            if image is not None:
                image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        if image is None or image.ndim != 3 or image.shape[2] != 3:
            raise ShardError(f"{shard.path}: the image of row {row} does not decode to an RGB picture")
        resize = self._options.resize
        if resize is not None and image.shape[:2] != resize:
            image = cv2.resize(image, (resize[1], resize[0]), interpolation=cv2.INTER_AREA)
        return image

    def __getitem__(self, index: int) -> dict[str, Any]:
        try:
            i = index.__index__()
        except AttributeError:
            raise TypeError(f"frame index must be an integer, got {type(index).__name__}") from None
        if i < 0:
            i += self._len
        if not 0 <= i < self._len:
            raise IndexError(f"frame {index} is out of range for {self._len} frames")
        k = bisect_right(self._starts, i) - 1
        f = i - self._starts[k]
        key, first, n = self._spans[k]
        reader = self._reader
        if reader is None or reader.pid != _getpid():
            reader = self._new_reader()
        last_key, shard = reader.last
        if key != last_key:
            shard = reader.get(key)
        row = first + f
        options = self._options
        if options.history == 0:
            image = self._decode(shard, row)
            vec = shard.floats[row].copy()
            item = {"image": image}
            for name, columns in _STATE_SLICES:
                item[name] = vec[columns]
            item["fingertip_distance"] = vec[_DISTANCE]
        else:
            item = self._history(shard, first, f, n)
            vec = shard.floats[row]
        horizon = options.action_horizon
        if horizon is None:
            item["action"] = vec[_ACTION].copy() if options.history else vec[_ACTION]
        else:
            frames, is_pad = horizon_window(f, n, horizon)
            item["action"] = shard.floats[first + frames, _ACTION]
            item["action_is_pad"] = is_pad
        item["phase"] = PHASES[shard.phase[row]]
        item["episode_index"] = self._indices[k]
        item["frame_index"] = np.int32(f)
        item["timestamp"] = shard.timestamp[row]
        item["text"] = self._texts[k]
        if self._several:
            item["source"] = self._episodes[k].source
        return item

    def _history(self, shard: _OpenShard, first: int, f: int, n: int) -> dict[str, Any]:
        frames, is_pad = history_window(f, n, self._options.history)
        rows = first + frames
        images, last_row, last = [], -1, None
        for row in rows.tolist():
            if row != last_row:
                last, last_row = self._decode(shard, row), row
            images.append(last)
        item: dict[str, Any] = {"image": np.stack(images), "image_is_pad": is_pad}
        block = shard.floats[rows]
        for name, columns in _STATE_SLICES:
            item[name] = block[:, columns]
            item[f"{name}_is_pad"] = is_pad.copy()
        item["fingertip_distance"] = block[:, _DISTANCE]
        item["fingertip_distance_is_pad"] = is_pad.copy()
        return item

    def __iter__(self) -> Iterator[dict[str, Any]]:
        for i in range(self._len):
            yield self[i]

    # --- other views ---------------------------------------------------------------------

    def iterable(
        self,
        shuffle: bool = True,
        seed: int = 0,
        rank: int | None = None,
        world_size: int | None = None,
        mix: int = 4,
    ) -> "FrameStream":
        """An iterable over the frames, split by shard across distributed ranks and DataLoader workers."""
        return FrameStream(self, shuffle=shuffle, seed=seed, rank=rank, world_size=world_size, mix=mix)

    def torch(self):
        """This dataset as a ``torch.utils.data.Dataset`` (needs torch)."""
        from catalog.torch_adapter import torch_dataset

        return torch_dataset(self)

    def close(self) -> None:
        """Close this process's open files (they reopen on the next access)."""
        if self._reader is not None and self._reader.pid == os.getpid():
            self._reader.close()

    def __enter__(self) -> "FrameDataset":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __getstate__(self) -> dict[str, Any]:
        """No open files, caches or statistics travel to another process; manifests go as dicts."""
        state = self.__dict__.copy()
        state["_reader"] = None
        state["_stats"] = None
        state["_manifests"] = [m.to_dict() for m in self._manifests]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state["_manifests"] = tuple(Manifest.from_dict(m) for m in state["_manifests"])
        self.__dict__.update(state)

    def __repr__(self) -> str:
        names = ", ".join(str(r) for r in self._roots)
        return (
            f"FrameDataset({names}: {len(self._episodes)} episodes, {self._len} frames, "
            f"history={self._options.history}, action_horizon={self._options.action_horizon})"
        )

    def _shard_spans(self) -> dict[int, list[tuple[int, int]]]:
        """{shard key: [(first position, frames), ...]} of the selected frames, in dataset order."""
        units: dict[int, list[tuple[int, int]]] = {}
        for (key, _, n), start in zip(self._spans, self._starts):
            if n:
                units.setdefault(key, []).append((start, n))
        return units


def _distributed() -> tuple[int, int]:
    dist = sys.modules.get("torch.distributed")
    if dist is not None and dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def _worker() -> tuple[int, int]:
    if "torch" in sys.modules:
        from torch.utils.data import get_worker_info

        info = get_worker_info()
        if info is not None:
            return info.id, info.num_workers
    return 0, 1


class FrameStream:
    """The frames of a dataset as an iterable, for large selections and distributed training.

    The unit of work is a shard (one frames file). Each epoch the shards are put in a
    seeded order (``shuffle``), dealt round-robin to the ``world_size`` ranks, and a
    rank's shards round-robin to its DataLoader workers; a worker reads ``mix`` shards
    at a time and yields their frames in a seeded random order. Every selected frame
    is yielded exactly once per epoch across all ranks and workers. Ranks get whole
    shards, so their frame counts can differ (see :meth:`frames_per_rank`); with fewer
    shards than ranks x workers some get none. ``rank``/``world_size`` default to
    ``torch.distributed``'s when it is initialised, else 0/1. Call :meth:`set_epoch`
    before each epoch (with non-persistent DataLoader workers) to reshuffle.
    """

    def __init__(self, dataset: FrameDataset, shuffle: bool, seed: int, rank, world_size, mix: int) -> None:
        if rank is None and world_size is None:
            rank, world_size = _distributed()
        elif rank is None or world_size is None:
            raise SpecError("give both rank and world_size, or neither")
        self.world_size = _non_negative("world_size", world_size, 1)
        self.rank = _non_negative("rank", rank, 0)
        if self.rank >= self.world_size:
            raise SpecError(f"rank must be < world_size ({self.world_size}), got {self.rank}")
        self.seed = _non_negative("seed", seed, 0)
        self.mix = _non_negative("mix", mix, 1)
        self.shuffle = bool(shuffle)
        self.dataset = dataset
        self.epoch = 0
        units = dataset._shard_spans()
        self._keys = sorted(units)
        self._units = [units[key] for key in self._keys]
        self._sizes = [sum(n for _, n in spans) for spans in self._units]

    def set_epoch(self, epoch: int) -> None:
        self.epoch = _non_negative("epoch", epoch, 0)

    def _order(self) -> list[int]:
        order = list(range(len(self._units)))
        if self.shuffle:
            order = np.random.default_rng([self.seed, self.epoch]).permutation(len(order)).tolist()
        return order

    def frames_per_rank(self) -> list[int]:
        """Frames each rank yields this epoch."""
        order = self._order()
        return [sum(self._sizes[u] for u in order[r :: self.world_size]) for r in range(self.world_size)]

    def __len__(self) -> int:
        return self.frames_per_rank()[self.rank]

    def positions(self, worker: int = 0, workers: int = 1) -> Iterator[int]:
        """Dataset positions one worker yields this epoch, in order."""
        mine = self._order()[self.rank :: self.world_size][worker::workers]
        for g in range(0, len(mine), self.mix):
            group = mine[g : g + self.mix]
            positions = np.concatenate(
                [np.arange(start, start + n, dtype=np.int64) for u in group for start, n in self._units[u]]
            )
            if self.shuffle:
                rng = np.random.default_rng([self.seed, self.epoch, *(self._keys[u] for u in group)])
                positions = rng.permutation(positions)
            yield from positions.tolist()

    def __iter__(self) -> Iterator[dict[str, Any]]:
        worker, workers = _worker()
        dataset = self.dataset
        for position in self.positions(worker, workers):
            yield dataset[position]

    def torch(self):
        """This stream as a ``torch.utils.data.IterableDataset`` (needs torch)."""
        from catalog.torch_adapter import torch_stream

        return torch_stream(self)


def open_dataset(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    history: int = 0,
    action_horizon: int | None = None,
    *,
    motion_type: str | Iterable[str] | None = None,
    intercept_setting: str | Iterable[str] | None = None,
    object: str | Iterable[str] | None = None,
    episodes: range | Iterable[int] | int | None = None,
    where: Callable[[Episode], bool] | None = None,
    resize: int | tuple[int, int] | None = None,
    verify: str = "sha256",
    cache_mb: float = 512,
) -> FrameDataset:
    """Open built slices or evaluated rollouts (folders with ``catalog.json``) as one dataset.

    ``paths`` is a folder or a list of folders (concatenated in order; items then carry
    ``source``). ``history=K`` stacks the K previous frames; ``action_horizon=H``
    returns H actions. Filters select episodes (see :meth:`FrameDataset.select`).
    ``resize=(height, width)`` (or one size) resizes images on load (``cv2.INTER_AREA``).
    ``verify`` is ``"sha256"`` or ``"checksums"`` (module docstring); ``cache_mb``
    bounds each process's cache of loaded shards.
    """
    if isinstance(paths, (str, os.PathLike)):
        roots = [Path(paths)]
    else:
        roots = [Path(p) for p in paths]
    if not roots:
        raise SpecError("catalog.open needs at least one folder")
    if verify not in VERIFY_MODES:
        raise SpecError(f"verify must be one of {list(VERIFY_MODES)}, got {verify!r}")
    if isinstance(cache_mb, bool) or not isinstance(cache_mb, (int, float)) or not cache_mb > 0:
        raise SpecError(f"cache_mb must be a positive number, got {cache_mb!r}")
    options = _Options(
        history=_non_negative("history", history, 0),
        action_horizon=None if action_horizon is None else _non_negative("action_horizon", action_horizon, 1),
        resize=_resize(resize),
        verify=verify,
        cache_bytes=int(cache_mb * (1 << 20)),
    )
    manifests, files, episodes_all, spans = [], [], [], []
    for source, root in enumerate(roots):
        manifest, source_episodes, source_spans = _load_source(root, source, verify, files)
        manifests.append(manifest)
        episodes_all.extend(source_episodes)
        spans.extend(source_spans)
    dataset = FrameDataset(roots, manifests, files, episodes_all, spans, options)
    filters = dict(
        motion_type=motion_type, intercept_setting=intercept_setting, object=object, episodes=episodes, where=where
    )
    if any(value is not None for value in filters.values()):
        dataset = dataset.select(**filters)
    return dataset
