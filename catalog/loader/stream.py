"""The iterable view of a dataset: shards in a seeded order, split by rank and worker,
each shard loaded once per epoch (:meth:`catalog.loader.dataset.FrameDataset.iterable`)."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from typing import Any, Protocol

import numpy as np

from catalog.loader.index import non_negative
from catalog.loader.torch_adapter import torch_stream
from schemas.errors import SpecError


class ShardedFrames(Protocol):
    """What a stream reads: items by position, and which positions each shard holds
    (:class:`catalog.loader.dataset.FrameDataset` is one)."""

    def __getitem__(self, index: int) -> dict[str, Any]: ...

    def shard_spans(self) -> dict[int, list[tuple[int, int]]]:
        """{shard key: [(first position, frames), ...]} in dataset order."""
        ...


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

    def __init__(
        self, dataset: ShardedFrames, shuffle: bool, seed: int, rank: int | None, world_size: int | None, mix: int
    ) -> None:
        if rank is None and world_size is None:
            rank, world_size = _distributed()
        elif rank is None or world_size is None:
            raise SpecError("give both rank and world_size, or neither")
        self.world_size = non_negative("world_size", world_size, 1)
        self.rank = non_negative("rank", rank, 0)
        if self.rank >= self.world_size:
            raise SpecError(f"rank must be < world_size ({self.world_size}), got {self.rank}")
        self.seed = non_negative("seed", seed, 0)
        self.mix = non_negative("mix", mix, 1)
        self.shuffle = bool(shuffle)
        self.dataset = dataset
        self.epoch = 0
        units = dataset.shard_spans()
        self._keys = sorted(units)
        self._units = [units[key] for key in self._keys]
        self._sizes = [sum(n for _, n in spans) for spans in self._units]

    def set_epoch(self, epoch: int) -> None:
        self.epoch = non_negative("epoch", epoch, 0)

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

    def torch(self) -> Any:
        """This stream as a ``torch.utils.data.IterableDataset`` (needs torch; typed ``Any``
        so that nothing here names a torch type)."""
        return torch_stream(self)

