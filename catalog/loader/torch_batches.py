"""Whole batches for ``torch.utils.data.DataLoader``, made in the worker: ``ds.torch().loader(...)``.

``torch_loader(ds, batch_size=32, shuffle=True, num_workers=2, seed=0)`` (also
``ds.torch().loader(...)``) returns a ready :class:`FrameLoader`, a
``torch.utils.data.DataLoader`` whose batches are those of
``DataLoader(ds.torch(), batch_size=32, shuffle=True, num_workers=2,
generator=torch.Generator().manual_seed(0))`` with the default collate: the same
positions in the same order, epoch after epoch (given the same ``persistent_workers``,
which changes how often DataLoader draws its workers' base seed from the generator),
and the same keys, dtypes, shapes and values (numbers as tensors with the batch
dimension first, strings as lists). Every item comes exactly once per epoch (the last
batch is short unless ``drop_last``). ``len(loader)`` is the number of batches;
``loader.batch_size`` is None (DataLoader's own batching is off), the batch size is
``loader.sampler.batch_size``.
It works with 0 workers, with ``fork`` or ``spawn`` workers, with ``pin_memory`` and
``persistent_workers``. A ShardError in a worker is raised in the main process as a
ShardError (DataLoader re-raises a worker's error as ``type(error)(traceback text)``; the
ShardError subclasses that take other arguments, e.g. ShardHashMismatch, would become a
RuntimeError, so a worker raises them as their nearest base class that takes a message,
with the subclass's name, message and traceback in the text). Like any DataLoader's, a
re-raised worker error keeps the iterator in a reference cycle (the error's traceback);
if it is caught and kept, the garbage collection that frees it later joins the workers
with DataLoader's 5 s timeout each: drop it (``error.__traceback__ = None``) when done.

Why. Default collate stacks each of an item's ~12 arrays into a fresh shared-memory
segment, and each segment travels to the main process as its own file descriptor
through multiprocessing's resource sharer (a socket connection and handshake per
descriptor). On a small VM, touching a fresh 4.8 MB segment per batch of 224 px images
costs about as much as decoding the batch. Here the sampler hands a worker a whole
batch of positions (``batch_size=None`` with a ``BatchSampler``), and the worker writes
the batch into one shared-memory slab of its own, reused from batch to batch (at most
:data:`SLABS` per worker; more are made, and not kept, while the main process still
holds that many batches). A slab's file descriptor travels to the main process once;
the main process keeps the slab mapped (until its worker has exited) and later batches
name it by a token. The main process gives out tensors that are views of the slab. When
the last of a batch's tensors (and anything viewing them) is freed, the slab goes back
to its worker. Consequences: a batch's tensors live in one slab (keeping one alive keeps
the batch's slab), and a tensor keeps the whole slab from reuse until it is freed, so
keep ``.clone()``s of what you store for long.

Measured (``benchmarks/dataloader.py``, 2,560 frames of 224 px, batch 32, 2 workers on a
2-core VM, load average 0.6-1.3, 4 runs): epochs at 1.04-1.68x one process's bare
``cv2.imdecode`` (the default DataLoader in the same runs: 0.43-0.49x); over ready-made
items 3.0-4.9x (default: 0.46-0.65x). The spread is the VM's: two processes of bare
decoding alone ran 1.4-1.95x one process at different times.

:meth:`FrameLoader.set_epoch` reseeds the order: after ``set_epoch(e)`` the next epoch's
order is the first epoch's order of ``seed + e``, whatever epochs came before (for
resuming). Without it, epochs follow one another as one generator's draws, as the
default DataLoader's do.

torch is optional: this module imports it only when a loader is made or a batch is built.
"""

from __future__ import annotations

import ctypes
import os
import threading
import weakref
from typing import Any

import numpy as np

from schemas.names import shorten

#: Slabs a worker keeps for reuse (prefetched batches, the batch in use, the one being freed).
SLABS = 6
_ALIGN = 64
_HEADER = _ALIGN  # byte 0: 1 while the main process holds the slab's batch


class FrameBatches:
    """A map-style dataset over batches: ``batches[[i, j, ...]]`` is the collated batch of
    ``frames[i], frames[j], ...`` (for ``DataLoader(batch_size=None, sampler=BatchSampler(...))``).
    In a DataLoader worker the batch is written to a reused shared-memory slab."""

    def __init__(self, frames: Any) -> None:
        self.frames = frames

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, indices: Any) -> Any:
        frames = self.frames
        if isinstance(indices, (int, np.integer)):
            indices = [indices]
        try:
            items = [frames[i] for i in indices]
        except Exception as error:
            if _in_worker():
                raise _rebuildable(error) from error
            raise
        return collate(items)


def _in_worker() -> bool:
    from torch.utils.data import get_worker_info

    return get_worker_info() is not None


def _rebuildable(error: Exception) -> Exception:
    """``error``, or its nearest base class that takes one message (e.g. ShardError for a
    ShardHashMismatch) with its message: DataLoader re-raises a worker's error in the main
    process as ``type(error)(message)``, and a RuntimeError when that call fails."""
    message = f"{type(error).__name__}: {error}"
    for cls in type(error).__mro__:
        if not issubclass(cls, Exception):
            break
        try:
            rebuilt = cls(message)
        except Exception:
            continue
        return error if cls is type(error) else rebuilt
    return error


class _Array(tuple):
    """Where a field lies in the batch's buffer: (dtype, shape, offset, nbytes)."""

    __slots__ = ()


def _kind(value: Any) -> tuple[np.dtype, tuple[int, ...]] | None:
    """The dtype and shape default collate gives one item's ``value`` (None: not a plain number array)."""
    if isinstance(value, (np.ndarray, np.generic)):
        dtype = value.dtype
        if dtype.kind not in "biufc" or dtype.byteorder not in "=|" and dtype.itemsize > 1:
            return None
        if dtype.kind == "f" and dtype.itemsize == 16 or dtype.kind == "c" and dtype.itemsize > 16:
            return None
        return dtype, value.shape
    if isinstance(value, bool):
        return np.dtype(bool), ()
    if isinstance(value, int):
        return np.dtype(np.int64), ()
    if isinstance(value, float):
        return np.dtype(np.float64), ()
    return None


def collate(items: list[dict[str, Any]]) -> Any:
    """``default_collate(items)`` for the dataset's items (dicts of numpy arrays, numbers and
    strings), built in one buffer: in a DataLoader worker, a reused shared-memory slab, and
    then returned wrapped, to be unpickled in the main process as the dict."""
    import torch
    from torch.utils.data import get_worker_info
    from torch.utils.data._utils.collate import default_collate

    m = len(items)
    first = items[0]
    plan: list[tuple[str, Any]] = []  # (key, _Array | list of strings | default collate's result)
    size = _HEADER
    for key, value in first.items():
        if isinstance(value, str):
            plan.append((key, [item[key] for item in items]))
            continue
        kind = _kind(value)
        if kind is None:
            plan.append((key, default_collate([item[key] for item in items])))
            continue
        dtype, shape = kind
        nbytes = m * dtype.itemsize * int(np.prod(shape, dtype=np.int64))
        plan.append((key, _Array((dtype, (m, *shape), size, nbytes))))
        size += -(-nbytes // _ALIGN) * _ALIGN
    shared = get_worker_info() is not None
    if shared:
        slabs = _slabs()
        slab, buffer, token = slabs.take(size)
    else:
        buffer = np.empty(size, dtype=np.uint8)
    try:
        fields = []
        for key, spec in plan:
            if type(spec) is _Array:
                dtype, shape, offset, nbytes = spec
                out = buffer[offset : offset + nbytes].view(dtype).reshape(shape)
                values = [item[key] for item in items]
                if not _fill(out, values):
                    # unequal shapes or dtypes: what default collate makes (or raises) of them
                    spec = default_collate(values)
            fields.append((key, spec))
    except BaseException:
        buffer[0] = 0
        raise
    if shared:
        return slabs.packed(slab, buffer, token, fields)
    return _views(buffer, fields, torch)


def _fill(out: np.ndarray, values: list[Any]) -> bool:
    """Copy ``values`` (one per item) into ``out`` if they all have its dtype and item shape."""
    dtype, shape = out.dtype, out.shape[1:]
    if out[0].nbytes >= 4096:
        for j, value in enumerate(values):
            if not isinstance(value, np.ndarray) or value.dtype != dtype or value.shape != shape:
                return False
            out[j] = value
        return True
    try:
        array = np.asarray(values)
    except ValueError:
        return False
    if array.dtype != dtype or array.shape != out.shape:
        return False
    out[...] = array
    return True


def _views(buffer: np.ndarray, fields: list[tuple[str, Any]], torch: Any) -> dict[str, Any]:
    out = {}
    for key, spec in fields:
        if type(spec) is _Array:
            dtype, shape, offset, nbytes = spec
            out[key] = torch.from_numpy(buffer[offset : offset + nbytes].view(dtype).reshape(shape))
        else:
            out[key] = spec
    return out


class _Packed:
    """A worker's batch in its slab; unpickled in the main process as the batch dict itself.
    The slab tensor itself (a file descriptor) travels only until the main process has
    registered it; after that, its token does."""

    __slots__ = ("slab", "token", "pid", "fields")

    def __init__(self, slab: Any, token: int, pid: int, fields: list[tuple[str, Any]]) -> None:
        self.slab, self.token, self.pid, self.fields = slab, token, pid, fields

    def __reduce__(self):
        return (_unpack, (self.slab, self.token, self.pid, self.fields))


def _release(flag: np.ndarray) -> None:
    flag[0] = 0


#: The main process's slabs, by token: {token: (worker pid, slab)}; a worker's slabs are
#: dropped once the worker has exited (checked when a new worker's first slab arrives).
_REGISTERED: dict[int, tuple[int, Any]] = {}
_REGISTERED_LOCK = threading.Lock()


def _forget_registered() -> None:
    """In a forked child (e.g. a later DataLoader's worker): the parent's slabs are not its own."""
    _REGISTERED.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_registered)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _register(token: int, pid: int, slab: Any) -> None:
    with _REGISTERED_LOCK:
        if all(p != pid for p, _ in _REGISTERED.values()):
            for dead in [t for t, (p, _) in _REGISTERED.items() if not _alive(p)]:
                del _REGISTERED[dead]
        _REGISTERED[token] = (pid, slab)


def _unpack(slab: Any, token: int, pid: int, fields: list[tuple[str, Any]]) -> dict[str, Any]:
    """The batch's tensors, views of its slab; the slab returns to its worker when the last
    of them (and of whatever views them) is freed."""
    import torch

    if slab is None:
        slab = _REGISTERED[token][1]
    elif token:
        _register(token, pid, slab)
    whole = slab.numpy()
    if token:
        whole[1] = 1  # registered: the worker sends the token from now on
    owner = (ctypes.c_ubyte * whole.size).from_buffer(whole)
    weakref.finalize(owner, _release, whole[:1])
    return _views(np.frombuffer(owner, dtype=np.uint8), fields, torch)


class _Slabs:
    """This worker's reusable shared-memory slabs: uint8 tensors whose header holds, at byte
    0, 1 while the main process holds the slab's batch (the main process sets it back to
    0), at byte 1, 1 once the main process has registered the slab, at bytes 8-15 its
    token (0 for a slab made for one batch only)."""

    def __init__(self) -> None:
        self.pid = os.getpid()
        self.slabs: list[tuple[Any, np.ndarray, int]] = []

    def take(self, nbytes: int) -> tuple[Any, np.ndarray, int]:
        for slab, buffer, token in self.slabs:
            if buffer[0] == 0 and buffer.size >= nbytes:
                buffer[0] = 1
                return slab, buffer, token
        slab = _shared(nbytes)
        buffer = slab.numpy()
        buffer[:_HEADER] = 0
        buffer[0] = 1
        token = 0
        if len(self.slabs) < SLABS:
            token = int.from_bytes(os.urandom(8), "little") | 1
            buffer[8:16].view(np.uint64)[0] = token
            self.slabs.append((slab, buffer, token))
        return slab, buffer, token

    def packed(self, slab: Any, buffer: np.ndarray, token: int, fields: list[tuple[str, Any]]) -> _Packed:
        return _Packed(None if token and buffer[1] else slab, token, self.pid, fields)


_SLABS: _Slabs | None = None


def _slabs() -> _Slabs:
    global _SLABS
    if _SLABS is None or _SLABS.pid != os.getpid():
        _SLABS = _Slabs()
    return _SLABS


def _shared(nbytes: int) -> Any:
    """A uint8 tensor of ``nbytes`` in shared memory (the way default collate allocates its own)."""
    import torch

    make = getattr(torch.UntypedStorage, "_new_shared", None)
    if make is None:
        return torch.empty(nbytes, dtype=torch.uint8).share_memory_()
    return torch.empty(0, dtype=torch.uint8).set_(make(nbytes), 0, (nbytes,), (1,))


def _passthrough(batch: Any) -> Any:
    return batch


def _define() -> None:
    if "FrameLoader" in globals():
        return
    from torch.utils.data import DataLoader

    class FrameLoader(DataLoader):
        """A DataLoader over :class:`FrameBatches` (see :func:`torch_loader`), with ``set_epoch``."""

        def __init__(self, frames: Any, sampler: Any, seed: int, **kwargs: Any) -> None:
            batches: Any = FrameBatches(frames)  # map-style: __getitem__ and __len__
            super().__init__(batches, batch_size=None, sampler=sampler, collate_fn=_passthrough, **kwargs)
            self.seed = seed

        def set_epoch(self, epoch: int) -> None:
            """Make the next epoch's order the first epoch's order of ``seed + epoch``."""
            self.generator.manual_seed(self.seed + epoch)

    FrameLoader.__module__ = __name__
    FrameLoader.__qualname__ = "FrameLoader"
    globals()["FrameLoader"] = FrameLoader


def __getattr__(name: str) -> Any:
    if name == "FrameLoader":
        _define()
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def torch_loader(
    frames: Any,
    batch_size: int = 32,
    shuffle: bool = False,
    num_workers: int = 0,
    seed: int = 0,
    drop_last: bool = False,
    **kwargs: Any,
) -> Any:
    """A ready ``DataLoader`` (:class:`FrameLoader`) over ``frames`` (a FrameDataset, or its
    ``ds.torch()`` wrapper) that builds whole batches in its workers; see the module docstring.

    Its batches equal those of ``DataLoader(ds.torch(), batch_size, shuffle, num_workers=...,
    drop_last=..., generator=torch.Generator().manual_seed(seed))`` with the default collate.
    Other keyword arguments go to ``DataLoader`` (``pin_memory``, ``persistent_workers``,
    ``prefetch_factor``, ``multiprocessing_context``, ``timeout``, ``worker_init_fn``,
    ``pin_memory_device``, ``in_order``); ``len(loader)`` is the number of batches.
    """
    import torch
    from torch.utils.data import BatchSampler, RandomSampler, SequentialSampler

    _define()
    for name in ("batch_sampler", "sampler", "collate_fn", "generator", "dataset"):
        if name in kwargs:
            raise TypeError(f"torch_loader does not take {name!r}")
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {shorten(repr(batch_size))}")
    frames = getattr(frames, "frames", frames)  # the ds.torch() wrapper
    generator = torch.Generator()
    generator.manual_seed(seed)
    positions = range(len(frames))
    order = RandomSampler(positions, generator=generator) if shuffle else SequentialSampler(positions)
    sampler = BatchSampler(order, batch_size, drop_last)
    return globals()["FrameLoader"](
        frames, sampler, seed, num_workers=num_workers, generator=generator, **kwargs
    )
