"""torch wrappers of the dataloader, for ``torch.utils.data.DataLoader``.

torch is optional: it is imported only when a wrapper is made or unpickled, never
by ``catalog`` itself. The wrapper classes are created on first use and published
as this module's attributes (``TorchFrames``, ``TorchFrameStream``), so workers
started with ``spawn`` can unpickle them. Items stay dicts of numpy arrays, strings
and numpy scalars; torch's default collate turns them into batched tensors (and
lists of strings). ``ds.torch().loader(batch_size=32, shuffle=True, num_workers=2, seed=0)``
gives a ready DataLoader with the same batches whose workers build whole batches in reused
shared memory (:mod:`catalog.loader.torch_batches`), several times cheaper to pass to the main process.
"""

from __future__ import annotations

from typing import Any

_CLASSES = ("TorchFrames", "TorchFrameStream")


def _define() -> None:
    if "TorchFrames" in globals():
        return
    from torch.utils.data import Dataset, IterableDataset

    class TorchFrames(Dataset):
        """A :class:`catalog.loader.dataset.FrameDataset` as a map-style torch Dataset."""

        def __init__(self, frames: Any) -> None:
            self.frames = frames

        def __len__(self) -> int:
            return len(self.frames)

        def __getitem__(self, index: int) -> dict[str, Any]:
            return self.frames[index]

        def __getitems__(self, indices: list[int]) -> list[dict[str, Any]]:
            """A batch's items (what DataLoader's fetcher asks for when it is defined)."""
            frames = self.frames
            return [frames[i] for i in indices]

        def loader(self, batch_size: int = 32, shuffle: bool = False, num_workers: int = 0, seed: int = 0,
                   drop_last: bool = False, **kwargs: Any) -> Any:
            """A ready DataLoader whose workers build whole batches (:func:`catalog.loader.torch_batches.torch_loader`):
            the batches of ``DataLoader(self, batch_size, shuffle, ..., generator=torch.Generator().manual_seed(seed))``,
            faster (one reused shared-memory slab per batch instead of a fresh segment per key)."""
            from catalog.loader.torch_batches import torch_loader

            return torch_loader(self.frames, batch_size, shuffle, num_workers, seed, drop_last, **kwargs)

    class TorchFrameStream(IterableDataset):
        """A :class:`catalog.loader.stream.FrameStream` as a torch IterableDataset (split by worker and rank)."""

        def __init__(self, stream: Any) -> None:
            self.stream = stream

        def __iter__(self):
            return iter(self.stream)

        def __len__(self) -> int:
            return len(self.stream)

        def set_epoch(self, epoch: int) -> None:
            self.stream.set_epoch(epoch)

    for cls in (TorchFrames, TorchFrameStream):
        cls.__module__ = __name__
        cls.__qualname__ = cls.__name__
        globals()[cls.__name__] = cls


def __getattr__(name: str) -> Any:
    if name in _CLASSES:
        _define()
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def torch_dataset(frames: Any) -> Any:
    """``frames`` (a FrameDataset) as a ``torch.utils.data.Dataset``."""
    _define()
    return globals()["TorchFrames"](frames)


def torch_stream(stream: Any) -> Any:
    """``stream`` (a FrameStream) as a ``torch.utils.data.IterableDataset``."""
    _define()
    return globals()["TorchFrameStream"](stream)
