"""The dataloader under torch's DataLoader with worker processes (skipped without torch)."""

from __future__ import annotations

import collections
import pickle

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import catalog  # noqa: E402
from catalog.store.manifest import load_manifest  # noqa: E402

from .conftest import frame_keys as _keys  # noqa: E402

pytestmark = pytest.mark.torch


def _all_keys(ds) -> collections.Counter:
    return collections.Counter((int(ds[i]["episode_index"]), int(ds[i]["frame_index"])) for i in range(len(ds)))


def test_map_style_with_two_workers_yields_every_frame_once_per_epoch(built):
    ds = catalog.open(built)
    ds[0]  # the parent has files open: workers must not share them
    loader = torch.utils.data.DataLoader(
        ds.torch(), batch_size=8, shuffle=True, num_workers=2, generator=torch.Generator().manual_seed(0)
    )
    expected = _all_keys(ds)
    assert sum(expected.values()) == load_manifest(built).frames
    for _ in range(2):
        batches = list(loader)
        assert _keys(batches) == expected
    batch = batches[0]
    assert batch["image"].dtype == torch.uint8 and batch["image"].shape[1:] == (32, 32, 3)
    assert batch["action"].dtype == torch.float32 and batch["action"].shape[1:] == (18,)
    assert batch["timestamp"].dtype == torch.float64 and isinstance(batch["text"], list)


def test_worker_batches_equal_direct_items(built):
    ds = catalog.open(built, history=2, action_horizon=3)
    loader = torch.utils.data.DataLoader(ds.torch(), batch_size=5, shuffle=False, num_workers=2)
    position = 0
    for batch in loader:
        for j in range(len(batch["frame_index"])):
            item = ds[position]
            for key in ("image", "image_is_pad", "palm_pose", "action", "action_is_pad"):
                np.testing.assert_array_equal(batch[key][j].numpy(), item[key])
            position += 1
    assert position == len(ds)


def test_iterable_with_two_workers_yields_every_frame_once(built):
    ds = catalog.open(built)
    stream = ds.iterable(seed=5, mix=2).torch()
    loader = torch.utils.data.DataLoader(stream, batch_size=4, num_workers=2)
    expected = _all_keys(ds)
    first = _keys(list(loader))
    assert first == expected
    stream.set_epoch(1)
    assert _keys(list(loader)) == expected


def test_iterable_shards_by_rank_and_worker(built):
    ds = catalog.open(built)
    total = collections.Counter()
    for rank in range(2):
        stream = ds.iterable(seed=2, rank=rank, world_size=2, mix=1).torch()
        seen = _keys(torch.utils.data.DataLoader(stream, batch_size=3, num_workers=2))
        assert sum(seen.values()) == len(stream)
        total += seen
    assert total == _all_keys(ds)


def test_batched_fetch_equals_items(built):
    """DataLoader's fetcher asks the wrapper for a batch at once (``__getitems__``)."""
    ds = catalog.open(built, history=1)
    batch = ds.torch().__getitems__([3, 0, 3])
    for item, i in zip(batch, (3, 0, 3)):
        np.testing.assert_array_equal(item["image"], ds[i]["image"])
        np.testing.assert_array_equal(item["palm_pose"], ds[i]["palm_pose"])


def test_wrappers_pickle_by_reference(built):
    """spawn-started workers unpickle the wrappers from catalog.loader.torch_adapter."""
    wrapped = catalog.open(built).torch()
    clone = pickle.loads(pickle.dumps(wrapped))
    assert type(clone).__module__ == "catalog.loader.torch_adapter" and len(clone) == len(wrapped)
    assert isinstance(clone, torch.utils.data.Dataset)
    stream = pickle.loads(pickle.dumps(catalog.open(built).iterable().torch()))
    assert isinstance(stream, torch.utils.data.IterableDataset)


def test_catalog_does_not_import_torch():
    import subprocess
    import sys

    code = "import catalog, catalog.loader.dataset, catalog.tables.stats, catalog.loader.torch_adapter, sys; print('torch' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"


def test_spawned_workers_unpickle_the_dataset(built):
    """One spawned worker (each imports torch afresh): the split between two workers is
    test_iterable_with_two_workers_yields_every_frame_once's."""
    ds = catalog.open(built, action_horizon=2)
    loader = torch.utils.data.DataLoader(
        ds.iterable(seed=1).torch(), batch_size=16, num_workers=1, multiprocessing_context="spawn"
    )
    assert _keys(list(loader)) == _all_keys(ds)
