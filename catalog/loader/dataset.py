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
integer frame arithmetic within one episode (``catalog.loader.windows``): padded slots
repeat the episode's first (history) or last (horizon) frame and are flagged. A
window decodes each of its frames once (their JPEGs read together); the decoded
frames of its last ``history`` rows are kept for the next item, so a sequential pass
decodes one frame per item.

Resizing. ``resize=(h, w)`` with ``resample="area"`` (the default) decodes in full and
resizes with ``cv2.INTER_AREA``. ``resample="jpeg"`` takes targets of half the
resolution or less from the JPEG decoder's own reduced-size decoding (1/2, 1/4 or
1/8, the largest that keeps the image at least as big as the target; then
``INTER_AREA`` for the rest), ~1.3x faster than ``"area"`` at half size (measured by
``benchmarks/dataloader.py``): a different resampling (libjpeg's scaled inverse DCT;
pixels differ from ``"area"`` by a few levels), deterministic for a given libjpeg-turbo
(simplejpeg's). Larger targets resize as
``"area"`` does.

Reading. Opening reads the manifests, the episodes tables and the ``episode_index``
and ``frame_index`` columns of every frames file, to build the index (position ->
episode -> shard row) from integer frame numbers. Files are opened lazily, in each
process separately (a DataLoader worker never inherits a parent's file handles or
caches). The first use of a shard in a process loads its float columns as one
float32 matrix and walks the image column's pages for each JPEG's byte offset
(``catalog.tables.pages``), reading the float columns from the bytes that walk (and hash)
read; a frame is then one ``preadv`` of its JPEG and one decode.
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

import os
from bisect import bisect_right
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, NoReturn

import cv2
import numpy as np

from catalog.loader.decode import DecodePlan, decode_plan, decode_rgb
from catalog.loader.index import ACTION_SLICE, DISTANCE_COLUMN, STATE_SLICES, Episode, Options, ShardFile
from catalog.loader.lerobot_keys import lerobot_item
from catalog.loader.selection import Selection, describe_episodes
from catalog.loader.shard_cache import OpenShard, ShardCache
from catalog.loader.stream import FrameStream
from catalog.loader.torch_adapter import torch_dataset
from catalog.loader.windows import episode_starts, history_span, horizon_span
from catalog.store.manifest import Manifest
from catalog.tables.stats import Stats, combine, load_stats
from schemas.errors import ShardError, SpecError
from schemas.scene import PHASES

_getpid = os.getpid
#: (state, its columns, its pad flag's key); ``_PAD_KEYS`` orders a window's pad flags.
_STATE_KEYS = tuple((name, columns, f"{name}_is_pad") for name, columns in STATE_SLICES)
_PAD_KEYS = ("image_is_pad", *(key for _, _, key in _STATE_KEYS), "fingertip_distance_is_pad")


class FrameDataset:
    """A sequence of frames over one or more folders; see the module docstring for items.

    Build one with :func:`open_dataset` (``catalog.open``). Safe to pass to
    ``torch.utils.data.DataLoader(num_workers>0)`` (directly or via :meth:`torch`):
    files are opened lazily in each process.
    """

    def __init__(
        self,
        roots: Iterable[Path],
        manifests: Iterable[Manifest],
        files: Iterable[ShardFile],
        episodes: Iterable[Episode],
        spans: Iterable[tuple[int, int, int]],
        options: Options,
        reader: ShardCache | None = None,
        stats: Stats | None = None,
        tasks: dict[str, int] | None = None,
    ) -> None:
        self._roots: tuple[Path, ...] = tuple(roots)
        self._manifests: tuple[Manifest, ...] = tuple(manifests)
        self._files: tuple[ShardFile, ...] = tuple(files)
        self._episodes: tuple[Episode, ...] = tuple(episodes)
        self._spans: tuple[tuple[int, int, int], ...] = tuple(spans)
        self._options: Options = options
        self._starts = episode_starts([n for _, _, n in self._spans])
        self._len = sum(n for _, _, n in self._spans)
        self._reader: ShardCache | None = reader
        self._stats = stats
        self._several = len(self._roots) > 1
        self._texts = [e.text for e in self._episodes]
        self._indices = [np.int64(e.episode_index) for e in self._episodes]
        #: Instruction -> task_index, in order of first use over the opened folders (kept by views).
        self._tasks: dict[str, int] = tasks if tasks is not None else {t: i for i, t in enumerate(dict.fromkeys(self._texts))}
        self._task_of = [self._tasks[t] for t in self._texts]
        self._plans: dict[int, DecodePlan] = {}

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

    def episode(self, k: int) -> FrameDataset:
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
    ) -> FrameDataset:
        """The episodes matching every given filter (values may be one or several; ``episodes``
        filters on ``episode_index``, e.g. ``range(0, 100)``; ``where`` is any predicate)."""
        return self.filtered(Selection.of(motion_type, intercept_setting, object, episodes, where))

    def filtered(self, selection: Selection) -> FrameDataset:
        """The episodes ``selection`` matches (what :meth:`select` builds from its arguments);
        SpecError when it matches none of them, saying what the folders hold (an empty
        dataset would only fail later, in a DataLoader, or train on nothing); ``episodes=[]``
        asks for none and gets an empty dataset."""
        keep = [k for k, e in enumerate(self._episodes) if selection.matches(e)]
        asked_none = selection.episodes is not None and len(selection.episodes) == 0  # episodes=[]: nothing, on purpose
        if not keep and self._episodes and not asked_none:
            raise SpecError(f"no episode matches the filters ({selection.describe()}); "
                            f"{'the folders hold' if len(self._roots) > 1 else 'the folder holds'} {describe_episodes(self._episodes)}")
        return self._view(keep)

    def _view(self, keep: Sequence[int]) -> FrameDataset:
        return FrameDataset(
            self._roots,
            self._manifests,
            self._files,
            [self._episodes[k] for k in keep],
            [self._spans[k] for k in keep],
            self._options,
            reader=self._reader,
            stats=self._stats,
            tasks=self._tasks,
        )

    @property
    def stats(self) -> Stats:
        """Normalisation statistics of the opened folders (all their frames, whatever the filters):
        ``ds.stats["action"].mean`` etc. (``catalog.tables.stats``); read from or written to ``stats.json``."""
        if self._stats is None:
            verify = self._options.verify == "sha256"
            self._stats = combine([load_stats(r, m, verify=verify) for r, m in zip(self._roots, self._manifests)])
        return self._stats

    # --- items -----------------------------------------------------------------------------

    def _new_reader(self) -> ShardCache:
        self._reader = ShardCache(self._files, self._options.verify, self._options.cache_bytes)
        return self._reader

    def _plan(self, resolution: int) -> DecodePlan:
        """The decode plan of this dataset's options for ``resolution`` px images (made once)."""
        plan = self._plans.get(resolution)
        if plan is None:
            plan = self._plans[resolution] = decode_plan(resolution, self._options.resize, self._options.resample)
        return plan

    def _decode(self, shard: OpenShard, row: int, data: np.ndarray | None = None, out: np.ndarray | None = None) -> np.ndarray:
        """The image of ``row`` (its JPEG bytes ``data`` if already read), checked and resized,
        written into ``out`` if given."""
        image = decode_rgb(shard.jpeg(row) if data is None else data, self._plan(shard.resolution), out)
        if image is None:
            self._refuse(shard, row)
        return image

    def _refuse(self, shard: OpenShard, row: int) -> NoReturn:
        """ShardError for a JPEG that does not decode to the picture catalog.json promises
        (looked at again with OpenCV, so that the message gives its real size)."""
        image = cv2.imdecode(shard.jpeg(row), cv2.IMREAD_COLOR)
        if image is None or image.ndim != 3 or image.shape[2] != 3 or image.shape[:2] == (shard.resolution,) * 2:
            raise ShardError(f"{shard.path}: the image of row {row} does not decode to an RGB picture")
        raise ShardError(
            f"{shard.path}: the image of row {row} is {image.shape[1]}x{image.shape[0]} px, "
            f"catalog.json says {shard.resolution}"
        )

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
        last_key, last = reader.last
        shard = last if key == last_key and last is not None else reader.get(key)
        row = first + f
        options = self._options
        floats = shard.floats
        item: dict[str, Any]
        if options.history == 0:
            item = {"image": self._decode(shard, row)}
            vec = floats[row].copy()
            for name, columns in STATE_SLICES:
                item[name] = vec[columns]
            item["fingertip_distance"] = vec[DISTANCE_COLUMN]
        else:
            item = self._history(reader, shard, first, f)
            vec = floats[row]
        horizon = options.action_horizon
        if horizon is None:
            item["action"] = vec[ACTION_SLICE].copy() if options.history else vec[ACTION_SLICE]
        else:
            stop, pad = horizon_span(f, n, horizon)
            is_pad = np.zeros(horizon, dtype=bool)
            if pad:
                item["action"] = floats[list(range(row, first + stop)) + [first + n - 1] * pad, ACTION_SLICE]
                is_pad[stop - f :] = True
            else:
                item["action"] = floats[row : first + stop, ACTION_SLICE].copy()
            item["action_is_pad"] = is_pad
        item["phase"] = PHASES[shard.phase[row]]
        item["episode_index"] = self._indices[k]
        item["frame_index"] = np.int32(f)
        item["timestamp"] = shard.timestamp[row]
        item["text"] = self._texts[k]
        if self._several:
            item["source"] = self._episodes[k].source
        if options.keys == "lerobot":
            return lerobot_item(item, i, self._task_of[k], options.image_dtype)
        return item

    @property
    def tasks(self) -> dict[str, int]:
        """The opened folders' instructions and their ``task_index`` (order of first use)."""
        return dict(self._tasks)

    def _history(self, reader: ShardCache, shard: OpenShard, first: int, f: int) -> dict[str, Any]:
        history = self._options.history
        pad, start = history_span(f, history)
        lo, hi = first + start, first + f + 1
        pads = np.zeros((len(_PAD_KEYS), history + 1), dtype=bool)
        if pad:
            block = shard.floats[[lo] * pad + list(range(lo, hi))]
            pads[:, :pad] = True
        else:
            block = shard.floats[lo:hi].copy()
        item: dict[str, Any] = {"image": self._window_images(reader, shard, pad, lo, hi), "image_is_pad": pads[0]}
        j = 1
        for name, columns, pad_key in _STATE_KEYS:
            item[name] = block[:, columns]
            item[pad_key] = pads[j]
            j += 1
        item["fingertip_distance"] = block[:, DISTANCE_COLUMN]
        item["fingertip_distance_is_pad"] = pads[j]
        return item

    def _window_images(self, reader: ShardCache, shard: OpenShard, pad: int, lo: int, hi: int) -> np.ndarray:
        """A window's frames stacked: ``pad`` copies of row ``lo``, then rows ``lo ... hi - 1``,
        each decoded once, straight into the item's array, those not kept read together.
        When windows come in order (this one ends one row after the last) or one starts an
        episode, copies of the frames of its last ``history`` rows are kept (per process)
        for the next, which shares all of them but one: one decode per item in a
        sequential pass, and no copies kept in random order."""
        out = np.empty((pad + hi - lo, *self._plan(shard.resolution).shape), dtype=np.uint8)
        kept_shard, kept_first, kept, last_hi = reader.recent
        in_order = kept_shard is shard and hi == last_hi + 1
        k0, k1 = (max(lo, kept_first), min(hi, kept_first + len(kept))) if in_order else (hi, hi)
        if k0 >= k1:
            k0 = k1 = hi
        self._decode_rows(shard, lo, k0, out[pad:])
        for row in range(k0, k1):
            out[pad + row - lo] = kept[row - kept_first]
        self._decode_rows(shard, k1, hi, out[pad + k1 - lo :])
        for j in range(pad):
            out[j] = out[pad]
        keep = max(0, hi - lo - self._options.history)
        starts_episode = pad == self._options.history
        kept = [out[pad + j].copy() for j in range(keep, hi - lo)] if in_order or starts_episode else []
        reader.recent = (shard, lo + keep, kept, hi)
        return out

    def _decode_rows(self, shard: OpenShard, lo: int, hi: int, out: np.ndarray) -> None:
        """Decode rows ``lo ... hi - 1`` into ``out[0 ... hi - lo - 1]``."""
        if lo < hi:
            for j, data in enumerate(shard.jpegs(lo, hi)):
                self._decode(shard, lo + j, data, out[j])

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
    ) -> FrameStream:
        """An iterable over the frames, split by shard across distributed ranks and DataLoader workers."""
        return FrameStream(self, shuffle=shuffle, seed=seed, rank=rank, world_size=world_size, mix=mix)

    def torch(self) -> Any:
        """This dataset as a ``torch.utils.data.Dataset`` (needs torch; typed ``Any`` so that
        nothing here names a torch type)."""
        return torch_dataset(self)

    def close(self) -> None:
        """Close this process's open files (they reopen on the next access)."""
        if self._reader is not None and self._reader.pid == os.getpid():
            self._reader.close()

    def __enter__(self) -> FrameDataset:
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

    def shard_spans(self) -> dict[int, list[tuple[int, int]]]:
        """{shard key: [(first position, frames), ...]} of the selected frames, in dataset order."""
        units: dict[int, list[tuple[int, int]]] = {}
        for (key, _, n), start in zip(self._spans, self._starts):
            if n:
                units.setdefault(key, []).append((start, n))
        return units
