"""``ds.torch().loader(...)`` (catalog.loader.torch_batches) against the default DataLoader (skipped without torch)."""

from __future__ import annotations

import collections
import gc
import itertools
import shutil

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import catalog  # noqa: E402
from catalog.loader.torch_batches import FrameBatches, torch_loader  # noqa: E402
from catalog.store.manifest import load_manifest  # noqa: E402
from schemas.errors import ShardError  # noqa: E402

from .conftest import frame_keys as _keys  # noqa: E402

pytestmark = pytest.mark.torch


def _default(ds, batch_size, shuffle, seed, drop_last=False, **kwargs):
    return torch.utils.data.DataLoader(
        ds.torch(), batch_size=batch_size, shuffle=shuffle, drop_last=drop_last,
        generator=torch.Generator().manual_seed(seed), **kwargs,
    )


def _assert_same_batches(expected, got) -> int:
    count = 0
    for a, b in itertools.zip_longest(expected, got):
        assert a is not None and b is not None, "different numbers of batches"
        assert list(a) == list(b)
        for key, value in a.items():
            if isinstance(value, torch.Tensor):
                assert isinstance(b[key], torch.Tensor), key
                assert b[key].dtype == value.dtype and b[key].shape == value.shape, key
                assert torch.equal(b[key], value), key
            else:
                assert type(b[key]) is type(value) and b[key] == value, key
        count += 1
    return count


@pytest.mark.parametrize(
    "options, batch_size, shuffle, drop_last",
    [({}, 7, True, False), ({"history": 1, "action_horizon": 3}, 5, False, False), ({"keys": "lerobot"}, 8, True, True)],
)
def test_batches_equal_the_default_dataloaders_in_process(built, options, batch_size, shuffle, drop_last):
    ds = catalog.open(built, **options)
    new = ds.torch().loader(batch_size=batch_size, shuffle=shuffle, seed=4, drop_last=drop_last)
    reference = _default(ds, batch_size, shuffle, 4, drop_last)
    assert len(new) == len(reference)
    for _ in range(2):  # the second epoch continues the generator as the default DataLoader does
        assert _assert_same_batches(reference, new) == len(reference)


def test_two_workers_give_the_default_batches_each_frame_once(built):
    ds = catalog.open(built)
    ds[0]  # the parent has files open: workers must not share them
    new = torch_loader(ds, batch_size=8, shuffle=True, num_workers=2, seed=1, persistent_workers=True)
    reference = _default(ds, 8, True, 1, num_workers=2, persistent_workers=True)
    expected = collections.Counter((int(ds[i]["episode_index"]), int(ds[i]["frame_index"])) for i in range(len(ds)))
    assert sum(expected.values()) == load_manifest(built).frames
    for _ in range(2):
        batches = list(new)
        assert _assert_same_batches(reference, batches) == len(new)
        assert _keys(batches) == expected
    batch = batches[0]
    assert batch["image"].dtype == torch.uint8 and batch["image"].shape == (8, 32, 32, 3)
    assert batch["timestamp"].dtype == torch.float64 and isinstance(batch["text"], list)


def test_order_is_fixed_by_the_seed_and_set_epoch(built):
    ds = catalog.open(built)

    def order(loader):
        return [i for batch in loader for i in zip(batch["episode_index"].tolist(), batch["frame_index"].tolist())]

    a, b = ds.torch().loader(batch_size=6, shuffle=True, seed=3), ds.torch().loader(batch_size=6, shuffle=True, seed=3)
    first = order(a)
    assert first == order(b) and first != order(ds.torch().loader(batch_size=6, shuffle=True, seed=4))
    second = order(a)
    assert second != first
    a.set_epoch(0)
    assert order(a) == first
    b.set_epoch(5)
    assert order(b) == order(ds.torch().loader(batch_size=6, shuffle=True, seed=8))
    assert order(ds.torch().loader(batch_size=6)) == [
        (int(ds[i]["episode_index"]), int(ds[i]["frame_index"])) for i in range(len(ds))
    ]


def test_spawned_workers_and_pinned_memory(built):
    """One spawned worker (each imports torch afresh): two workers' batches are
    test_two_workers_give_the_default_batches_each_frame_once's."""
    ds = catalog.open(built, action_horizon=2)
    new = ds.torch().loader(batch_size=16, shuffle=True, num_workers=1, seed=2, multiprocessing_context="spawn")
    assert _assert_same_batches(_default(ds, 16, True, 2), new) == len(new)
    pinned = ds.torch().loader(batch_size=16, num_workers=1, pin_memory=True)
    assert _assert_same_batches(_default(ds, 16, False, 0), pinned) == len(pinned)


def test_worker_slabs_are_reused_and_batches_stay_intact(built):
    """Batches kept by the caller keep their slab: later batches never overwrite them."""
    ds = catalog.open(built)
    kept = list(ds.torch().loader(batch_size=4, num_workers=2, prefetch_factor=1))
    for batch in kept[::3]:
        del batch
    gc.collect()
    positions = iter(range(len(ds)))
    for batch in kept:
        for j in range(len(batch["frame_index"])):
            i = next(positions)
            np.testing.assert_array_equal(batch["image"][j].numpy(), ds[i]["image"])
            np.testing.assert_array_equal(batch["action"][j].numpy(), ds[i]["action"])


def test_a_corrupt_shard_raises_shard_error_in_the_main_process(built, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(built, copy)
    path = copy / load_manifest(copy).shards[1].files["frames"].path
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x5A
    path.write_bytes(bytes(data))
    ds = catalog.open(copy)
    for workers in (0, 2):
        # Not pytest.raises: DataLoader re-raises a worker's error from a frame that the
        # traceback keeps (a reference cycle), so the iterator is freed by a later garbage
        # collection, whose join of the workers then waits 5 s each (any DataLoader does so).
        try:
            list(ds.torch().loader(batch_size=8, num_workers=workers))
        except ShardError as error:
            message = str(error)
            error.__traceback__ = None
        else:
            pytest.fail("no ShardError")
        assert path.name in message


def test_batch_of_positions_in_process_is_plain_tensors(built):
    ds = catalog.open(built)
    batch = FrameBatches(ds)[[2, 0, 2]]
    assert batch["frame_index"].tolist() == [int(ds[i]["frame_index"]) for i in (2, 0, 2)]
    assert batch["phase"] == [ds[i]["phase"] for i in (2, 0, 2)]
    with pytest.raises(TypeError, match="sampler"):
        torch_loader(ds, sampler=[0])


def test_batches_after_the_first_name_their_slab_by_token(built):
    """Each worker's slabs travel to the main process once and are reused: the main process
    registers at most SLABS of them per worker, however many batches pass."""
    from catalog.loader import torch_batches

    ds = catalog.open(built)
    loader = ds.torch().loader(batch_size=2, num_workers=2, persistent_workers=True)
    for _ in range(3):
        count = sum(1 for _ in loader)
    pids = {w.pid for w in loader._iterator._workers}
    registered = [pid for pid, _ in torch_batches._REGISTERED.values() if pid in pids]
    assert count == len(loader) > 2 * torch_batches.SLABS
    assert 2 <= len(registered) <= 2 * torch_batches.SLABS
