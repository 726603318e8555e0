"""catalog.open: items equal what was written, windows, filters, folders, streams, statistics,
and corrupt files refused with their name."""

from __future__ import annotations

import json
import multiprocessing
import pickle
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

import catalog
from catalog.loader.dataset import FrameDataset
from catalog.loader.stream import FrameStream
from catalog.store.manifest import Manifest, load_manifest, write_manifest
from catalog.tables.shard import ShardWriter
from catalog.tables.stats import STATS_NAME, compute_stats, load_stats, write_stats
from schemas.errors import ShardError, SpecError
from schemas.motion import ArcToken, HarmonicToken, Motion, Track
from schemas.scene import PHASES
from schemas.tables import STATE_COLUMNS

from .conftest import (
    CODE,
    SETTINGS,
    make_episode,
    make_frames,
    make_images,
    make_spec,
    write_slice,
)

EPISODES, SHARD_SIZE = 5, 2


def _rgb(jpeg: bytes) -> np.ndarray:
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _expected(episodes: int = EPISODES, seed: int = 0):
    """What write_slice wrote: per episode (spec, frames, images)."""
    return [make_episode(i, seed) for i in range(episodes)]


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("built") / "linear-fast"
    write_slice(root, episodes=EPISODES, shard_size=SHARD_SIZE)
    return root


@pytest.fixture
def copy(tmp_path, built) -> Path:
    """A private copy of the built slice, free to tamper with."""
    import shutil

    target = tmp_path / "copy"
    shutil.copytree(built, target)
    (target / STATS_NAME).unlink(missing_ok=True)
    return target


def _flip(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x5A
    path.write_bytes(bytes(data))


def _frames_path(root: Path, shard: int = 0) -> Path:
    return root / load_manifest(root).shards[shard].files["frames"].path


# --- items ---------------------------------------------------------------------------------


def test_every_item_equals_what_was_written(built):
    ds = catalog.open(built)
    expected = _expected()
    assert len(ds) == load_manifest(built).frames == sum(f.num_frames for _, f, _ in expected)
    i = 0
    for e, (spec, frames, images) in enumerate(expected):
        for f in range(frames.num_frames):
            item = ds[i]
            assert item["image"].dtype == np.uint8 and item["image"].shape == (32, 32, 3)
            np.testing.assert_array_equal(item["image"], _rgb(images[f]))
            for name in STATE_COLUMNS:
                assert item[name].dtype == np.float32
                np.testing.assert_array_equal(item[name], getattr(frames, name)[f])
            np.testing.assert_array_equal(item["action"], frames.action[f])
            assert item["action"].shape == (18,)
            assert item["fingertip_distance"] == frames.fingertip_distance[f]
            assert item["episode_index"] == e and item["episode_index"].dtype == np.int64
            assert item["frame_index"] == f and item["frame_index"].dtype == np.int32
            assert item["timestamp"] == f / 20 and item["timestamp"].dtype == np.float64
            assert item["text"] == spec.text
            assert item["phase"] == PHASES[frames.phase[f]]
            assert "source" not in item and "action_is_pad" not in item
            i += 1
    assert i == len(ds)


def test_indexing_rules(built):
    ds = catalog.open(built)
    np.testing.assert_array_equal(ds[-1]["action"], ds[len(ds) - 1]["action"])
    assert ds[np.int64(3)]["frame_index"] == 3
    with pytest.raises(IndexError):
        ds[len(ds)]
    with pytest.raises(IndexError):
        ds[-len(ds) - 1]
    with pytest.raises(TypeError):
        ds[1.0]
    assert sum(1 for _ in ds) == len(ds)


def test_items_do_not_alias_the_cache(built):
    ds = catalog.open(built)
    first = ds[0]
    first["palm_pose"][:] = 99.0
    first["action"][:] = 99.0
    again = ds[0]
    assert not np.any(again["palm_pose"] == 99.0) and not np.any(again["action"] == 99.0)


def test_history_stacks_previous_frames_and_masks_the_episode_start(built):
    history = 3
    ds = catalog.open(built, history=history)
    expected = _expected()
    starts = np.cumsum([0] + [f.num_frames for _, f, _ in expected])
    for e, (_, frames, images) in enumerate(expected):
        for f in (0, 1, 2, 3, frames.num_frames - 1):
            item = ds[int(starts[e]) + f]
            wanted = [max(f - k, 0) for k in range(history, -1, -1)]
            pad = [f - k < 0 for k in range(history, -1, -1)]
            assert item["image"].shape == (history + 1, 32, 32, 3)
            assert item["image_is_pad"].tolist() == pad
            for j, source in enumerate(wanted):
                np.testing.assert_array_equal(item["image"][j], _rgb(images[source]))
            for name in STATE_COLUMNS:
                np.testing.assert_array_equal(item[name], getattr(frames, name)[wanted])
                assert item[f"{name}_is_pad"].tolist() == pad
            np.testing.assert_array_equal(item["fingertip_distance"], frames.fingertip_distance[wanted])
            np.testing.assert_array_equal(item["action"], frames.action[f])
            assert item["frame_index"] == f


def test_action_horizon_masks_the_episode_end(built):
    horizon = 4
    ds = catalog.open(built, action_horizon=horizon)
    expected = _expected()
    position = 0
    for _, frames, _ in expected:
        n = frames.num_frames
        for f in (0, n - 3, n - 1):
            item = ds[position + f]
            wanted = [min(f + k, n - 1) for k in range(horizon)]
            assert item["action"].shape == (horizon, 18) and item["action"].dtype == np.float32
            np.testing.assert_array_equal(item["action"], frames.action[wanted])
            assert item["action_is_pad"].tolist() == [f + k >= n for k in range(horizon)]
        position += n
    one = catalog.open(built, action_horizon=1)[0]
    assert one["action"].shape == (1, 18) and one["action_is_pad"].tolist() == [False]


def test_windows_never_cross_episodes(built):
    ds = catalog.open(built, history=2, action_horizon=3)
    for k, episode in enumerate(ds.episodes):
        frames = ds.episode_frames(k)
        first, last = ds[frames[0]], ds[frames[-1]]
        assert first["image_is_pad"].tolist() == [True, True, False]
        assert last["action_is_pad"].tolist() == [False, True, True]
        assert first["episode_index"] == last["episode_index"] == episode.episode_index


def test_resize_on_load(built):
    ds = catalog.open(built, resize=(16, 24))
    _, _, images = make_episode(0)
    want = cv2.resize(_rgb(images[0]), (24, 16), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(ds[0]["image"], want)
    assert catalog.open(built, resize=8)[0]["image"].shape == (8, 8, 3)
    with pytest.raises(SpecError):
        catalog.open(built, resize=(0, 4))


def _reduced_rgb(jpeg: bytes, scale: int) -> np.ndarray:
    flags = getattr(cv2, f"IMREAD_REDUCED_COLOR_{scale}")
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(jpeg, np.uint8), flags), cv2.COLOR_BGR2RGB)


def test_resample_jpeg_decodes_at_reduced_size(built):
    """resample="jpeg": targets of half the resolution or less come from libjpeg's 1/2, 1/4, 1/8
    decoding (then INTER_AREA for the rest); bigger ones from the full decode, as "area"."""
    _, _, images = make_episode(0)
    half = catalog.open(built, resize=16, resample="jpeg")[0]["image"]
    np.testing.assert_array_equal(half, _reduced_rgb(images[0], 2))
    np.testing.assert_array_equal(catalog.open(built, resize=8, resample="jpeg")[0]["image"], _reduced_rgb(images[0], 4))
    np.testing.assert_array_equal(catalog.open(built, resize=4, resample="jpeg")[0]["image"], _reduced_rgb(images[0], 8))
    want = cv2.resize(_reduced_rgb(images[0], 2), (12, 10), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(catalog.open(built, resize=(10, 12), resample="jpeg")[0]["image"], want)
    for size in (20, 32):
        np.testing.assert_array_equal(
            catalog.open(built, resize=size, resample="jpeg")[0]["image"], catalog.open(built, resize=size)[0]["image"]
        )
    area = catalog.open(built, resize=16)[0]["image"]
    assert half.shape == area.shape and not np.array_equal(half, area)  # another resampling, documented as such
    windows = catalog.open(built, resize=8, resample="jpeg", history=2)
    np.testing.assert_array_equal(windows[5]["image"][1], catalog.open(built, resize=8, resample="jpeg")[4]["image"])
    with pytest.raises(SpecError, match="resample"):
        catalog.open(built, resize=16, resample="cubic")


def test_sequential_windows_decode_each_frame_once(built, monkeypatch):
    """A sequential pass reuses the previous window's frames (one decode per item) and returns
    what random access returns; items never alias the frames kept for the next window."""
    import simplejpeg

    ds = catalog.open(built, history=2, action_horizon=3)
    expected = {i: ds[i] for i in np.random.default_rng(2).permutation(len(ds)).tolist()}
    decodes = []
    real = simplejpeg.decode_jpeg
    monkeypatch.setattr(simplejpeg, "decode_jpeg", lambda *a, **k: decodes.append(1) or real(*a, **k))
    fresh = catalog.open(built, history=2, action_horizon=3)
    for i in range(len(fresh)):
        item = fresh[i]
        for key, value in expected[i].items():
            np.testing.assert_array_equal(item[key], value)
        item["image"][:] = 0
    assert len(decodes) == len(fresh)


def test_bad_options_are_refused(built, tmp_path):
    for kwargs in ({"history": -1}, {"action_horizon": 0}, {"verify": "md5"}, {"cache_mb": 0}, {"history": 1.5},
                   {"resize": True}, {"episodes": True}, {"episodes": [1, "2"]}, {"object": "anvil"}):
        with pytest.raises(SpecError):
            catalog.open(built, **kwargs)
    with pytest.raises(ShardError, match="catalog.json"):
        catalog.open(tmp_path)
    with pytest.raises(SpecError):
        catalog.open([])


# --- episodes and filters ------------------------------------------------------------------


def _mixed_slice(root: Path) -> None:
    """Six episodes over motion types, settings and objects."""
    kinds = [("linear", "fast"), ("circular", "medium"), ("harmonic", "slow")] * 2
    records = []
    for first in (0, 3):
        with ShardWriter(root, first, first + 3, SETTINGS) as writer:
            for i in range(first, first + 3):
                motion_type, setting = kinds[i]
                base = make_spec(i, num_frames=50)
                # a faint arc and wobble on top, so that each label fits the motion
                wobble = Track((HarmonicToken((0.0, 0.0), 0.0, 0.01, 1.0, 0.0, 2.0), ArcToken((0.0, 0.0), 0.01, 0.1, 0.0, 1, 2.0)))
                motion = Motion(base.motion.base, (wobble,))
                spec = replace(base, motion=motion, motion_type=motion_type, intercept_setting=setting)
                rng = np.random.default_rng([3, i])
                frames = make_frames(spec, rng)
                writer.add_episode(spec, frames, make_images(frames.num_frames, rng))
        records.append(writer.record)
    write_manifest(root, Manifest.create("test-1k", 1, SETTINGS, records, code=CODE))


def test_filters_select_episodes(tmp_path):
    root = tmp_path / "mixed"
    _mixed_slice(root)
    everything = catalog.open(root)
    assert [e.motion_type for e in everything.episodes] == ["linear", "circular", "harmonic"] * 2
    circular = catalog.open(root, motion_type="circular")
    assert [e.episode_index for e in circular.episodes] == [1, 4]
    assert len(circular) == 100
    assert {int(circular[i]["episode_index"]) for i in range(len(circular))} == {1, 4}
    both = catalog.open(root, motion_type=["linear", "harmonic"], intercept_setting="slow")
    assert [e.episode_index for e in both.episodes] == [2, 5]
    cans = catalog.open(root, object="soda_can", episodes=range(2, 6))
    assert [e.episode_index for e in cans.episodes] == [3, 5]
    picked = everything.select(where=lambda e: e.episode_index % 3 == 0)
    assert [e.episode_index for e in picked.episodes] == [0, 3]
    assert len(catalog.open(root, episodes=[])) == 0  # asked for none
    with pytest.raises(SpecError, match=r"no episode matches the filters \(motion_type=\['linear'\], intercept_setting="
                                        r"\['slow'\]\); the folder holds 6 episodes: motion_type \['circular', 'harmonic', "
                                        r"'linear'\], intercept_setting \['fast', 'medium', 'slow'\]"):
        catalog.open(root, motion_type="linear", intercept_setting="slow")  # before: 0 frames, silently
    with pytest.raises(SpecError, match="no episode matches the filters"):
        circular.select(where=lambda e: e.episode_index == 0)
    for bad in ({"motion_type": "lineer"}, {"intercept_setting": "quick"}, {"object": "teapot"}, {"episodes": ["1"]}):
        with pytest.raises(SpecError):
            catalog.open(root, **bad)


def test_episode_access(built):
    ds = catalog.open(built)
    expected = _expected()
    assert [e.episode_index for e in ds.episodes] == list(range(EPISODES))
    episode = ds.episodes[3]
    spec, frames, _ = expected[3]
    assert (episode.episode_id, episode.num_frames, episode.text, episode.object) == (
        spec.episode_id, frames.num_frames, spec.text, spec.object
    )
    assert episode.policy is None and episode.status is None
    one = ds.episode(3)
    assert len(one) == frames.num_frames and one.episodes == (episode,)
    assert [int(one[f]["frame_index"]) for f in range(len(one))] == list(range(frames.num_frames))
    np.testing.assert_array_equal(one[2]["joint_angles"], frames.joint_angles[2])
    assert ds.episode_frames(3) == range(sum(f.num_frames for _, f, _ in expected[:3]), sum(
        f.num_frames for _, f, _ in expected[:4]))
    assert len(ds.episode(-1)) == expected[-1][1].num_frames
    with pytest.raises(IndexError):
        ds.episode(EPISODES)


def test_several_folders_concatenate_with_a_source(tmp_path, built):
    other = tmp_path / "other"
    write_slice(other, episodes=3, shard_size=3, seed=9)
    ds = catalog.open([built, other])
    assert len(ds) == load_manifest(built).frames + load_manifest(other).frames
    assert ds.sources == (built, other)
    last = ds[len(ds) - 1]
    spec, frames, images = make_episode(2, 9)
    assert last["source"] == 1 and last["episode_index"] == 2
    np.testing.assert_array_equal(last["image"], _rgb(images[-1]))
    np.testing.assert_array_equal(last["keypoints"], frames.keypoints[-1])
    assert ds[0]["source"] == 0
    assert [e.source for e in ds.episodes] == [0] * EPISODES + [1] * 3


def test_rollouts_with_short_episodes(tmp_path):
    root = tmp_path / "run"
    with ShardWriter(root, 0, 2, SETTINGS, rollout=True) as writer:
        for i, (status, keep) in enumerate((("ok", make_spec(0).num_frames + 4), ("error", 7))):
            spec = make_spec(i)
            rng = np.random.default_rng([5, i])
            frames = make_frames(spec, rng, num_frames=keep)
            error = "policy raised" if status == "error" else None
            images = make_images(frames.num_frames, rng)
            writer.add_episode(spec, frames, images, policy="p", status=status, error=error)
    write_manifest(root, Manifest.create("test-1k", 1, SETTINGS, [writer.record], code=CODE, extra={"policy": "p"}))
    ds = catalog.open(root, action_horizon=3)
    assert [(e.status, e.policy, e.num_frames) for e in ds.episodes] == [
        ("ok", "p", make_spec(0).num_frames + 4), ("error", "p", 7)
    ]
    last = ds[len(ds) - 1]
    assert last["frame_index"] == 6 and last["action_is_pad"].tolist() == [False, True, True]
    assert len(ds.select(where=lambda e: e.status == "ok")) == make_spec(0).num_frames + 4


# --- processes, pickling, bounded memory ------------------------------------------------------


def test_pickles_without_open_files(built):
    ds = catalog.open(built, history=1)
    before = ds[10]
    clone = pickle.loads(pickle.dumps(ds))
    assert clone._reader is None
    after = clone[10]
    for key in ("image", "palm_pose", "image_is_pad"):
        np.testing.assert_array_equal(before[key], after[key])


def _child_read(ds: FrameDataset, positions, queue) -> None:
    queue.put([(int(ds[i]["episode_index"]), int(ds[i]["frame_index"]), ds[i]["image"].tobytes()) for i in positions])


def test_forked_processes_read_with_their_own_files(built):
    ds = catalog.open(built)
    parent = []
    for i in range(len(ds)):
        item = ds[i]
        parent.append((int(item["episode_index"]), int(item["frame_index"]), item["image"].tobytes()))
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    halves = [range(0, len(ds), 2), range(1, len(ds), 2)]
    children = [context.Process(target=_child_read, args=(ds, h, queue)) for h in halves]
    for child in children:
        child.start()
    results = [queue.get(timeout=60) for _ in children]
    for child in children:
        child.join(timeout=60)
        assert child.exitcode == 0
    assert sorted(results[0] + results[1]) == sorted(parent)


def test_cache_is_bounded(built):
    ds = catalog.open(built, cache_mb=1e-6)
    order = np.random.default_rng(0).permutation(len(ds))
    for i in order:
        ds[int(i)]
        assert len(ds._reader.cache) == 1
    roomy = catalog.open(built)
    for i in order:
        roomy[int(i)]
    assert len(roomy._reader.cache) == len(load_manifest(built).shards)
    roomy.close()
    assert not roomy._reader.cache
    assert roomy[0]["frame_index"] == 0


def test_threads_share_a_dataset_while_shards_are_evicted(built):
    from concurrent.futures import ThreadPoolExecutor

    ds = catalog.open(built, cache_mb=1e-6)
    expected = [(ds[i]["image"].tobytes(), ds[i]["palm_pose"].tobytes()) for i in range(len(ds))]
    order = np.random.default_rng(1).permutation(len(ds)).tolist() * 3

    def read(i):
        item = ds[i]
        return i, item["image"].tobytes(), item["palm_pose"].tobytes()

    with ThreadPoolExecutor(4) as pool:
        for i, image, palm in pool.map(read, order):
            assert (image, palm) == expected[i]


# --- the iterable stream ---------------------------------------------------------------------


def test_stream_yields_every_frame_once_across_ranks_and_workers(built):
    ds = catalog.open(built)
    seen = []
    for rank in range(2):
        stream = ds.iterable(seed=3, rank=rank, world_size=2, mix=2)
        rank_positions = [p for w in range(2) for p in stream.positions(w, 2)]
        assert len(rank_positions) == len(stream) == stream.frames_per_rank()[rank]
        seen.extend(rank_positions)
    assert sorted(seen) == list(range(len(ds)))


def test_stream_shuffles_deterministically_by_seed_and_epoch(built):
    ds = catalog.open(built)
    a, b = ds.iterable(seed=1), ds.iterable(seed=1)
    assert list(a.positions()) == list(b.positions())
    assert sorted(a.positions()) == list(range(len(ds)))
    assert list(a.positions()) != list(range(len(ds)))
    first = list(a.positions())
    a.set_epoch(1)
    assert list(a.positions()) != first and sorted(a.positions()) == list(range(len(ds)))
    assert list(ds.iterable(seed=2).positions()) != first
    assert list(ds.iterable(shuffle=False).positions()) == list(range(len(ds)))


def test_stream_items_are_dataset_items(built):
    ds = catalog.open(built, action_horizon=2)
    stream = ds.iterable(seed=4)
    for position, item in zip(stream.positions(), stream):
        np.testing.assert_array_equal(item["action"], ds[position]["action"])
        assert item["frame_index"] == ds[position]["frame_index"]


def test_stream_arguments(built):
    ds = catalog.open(built)
    with pytest.raises(SpecError):
        ds.iterable(rank=2, world_size=2)
    with pytest.raises(SpecError):
        ds.iterable(rank=0)
    with pytest.raises(SpecError):
        ds.iterable(mix=0)
    lonely = ds.iterable(rank=3, world_size=4)
    assert isinstance(lonely, FrameStream) and list(lonely.positions()) == []


# --- statistics ------------------------------------------------------------------------------


def _all_frames(expected) -> dict[str, np.ndarray]:
    names = (*STATE_COLUMNS, "action", "fingertip_distance")
    return {n: np.concatenate([getattr(f, n) for _, f, _ in expected]).astype(np.float64) for n in names}


def test_stats_match_numpy_and_are_stored(copy):
    ds = catalog.open(copy)
    stats = ds.stats
    columns = _all_frames(_expected())
    for name, values in columns.items():
        column = stats[name]
        assert column.count == len(values)
        np.testing.assert_allclose(column.mean, values.mean(axis=0), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(column.std, values.std(axis=0), rtol=1e-10, atol=1e-12)
        np.testing.assert_array_equal(column.min, values.min(axis=0))
        np.testing.assert_array_equal(column.max, values.max(axis=0))
    assert stats["fingertip_distance"].mean.shape == () and stats["action"].std.shape == (18,)
    assert not (copy / STATS_NAME).exists()  # this manifest lists none: computed in memory, nothing written


def test_listed_stats_are_served_only_while_their_hash_matches(copy):
    """stats.json is covered by the manifest's hash: an edited file is refused, never served."""
    manifest = load_manifest(copy)
    good = compute_stats(copy)
    record = write_stats(copy, good)
    listed = Manifest.create(manifest.slice, manifest.seed, manifest.settings, manifest.shards, code=manifest.code,
                             stats=record)
    write_manifest(copy, listed)
    assert listed.hash != manifest.hash
    np.testing.assert_array_equal(catalog.open(copy).stats["action"].mean, good["action"].mean)
    path = copy / STATS_NAME
    data = json.loads(path.read_text())
    data["columns"]["action"]["mean"] = [5.0] * 18
    path.write_text(json.dumps(data, sort_keys=True, indent=2) + "\n")
    with pytest.raises(ShardError, match="stats.json"):
        load_stats(copy)
    with pytest.raises(ShardError, match="stats.json"):
        _ = catalog.open(copy).stats


def test_stats_never_read_the_image_column(copy):
    """A corrupted image page would fail its checksum if it were read; the statistics do not notice it."""
    path = _frames_path(copy)
    _, _, images = make_episode(0)
    _flip(path, path.read_bytes().find(images[3]) + 20)
    stats = compute_stats(copy)
    assert stats.frames == load_manifest(copy).frames
    with pytest.raises(ShardError, match="sha256"):
        compute_stats(copy, verify=True)


def test_stats_of_several_folders_pool_their_frames(tmp_path, built):
    other = tmp_path / "other"
    write_slice(other, episodes=3, shard_size=2, seed=4)
    stats = catalog.open([built, other]).stats
    columns = _all_frames(_expected() + _expected(3, 4))
    for name in ("joint_poses", "fingertip_distance"):
        np.testing.assert_allclose(stats[name].mean, columns[name].mean(axis=0), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(stats[name].std, columns[name].std(axis=0), rtol=1e-9, atol=1e-12)
        np.testing.assert_array_equal(stats[name].min, columns[name].min(axis=0))


# --- corrupt data -----------------------------------------------------------------------------


def test_truncated_frames_file_is_named_at_open(copy):
    path = _frames_path(copy, 1)
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(ShardError, match=rf"{path.name}.*truncated"):
        catalog.open(copy)


def test_missing_file_is_named_at_open(copy):
    path = _frames_path(copy, 2)
    path.unlink()
    with pytest.raises(ShardError, match=rf"{path.name}.*missing"):
        catalog.open(copy, verify="checksums")


@pytest.mark.parametrize("verify", ["sha256", "checksums"])
def test_tampered_image_is_never_returned(copy, verify):
    path = _frames_path(copy)
    _, _, images = make_episode(1)
    _flip(path, path.read_bytes().find(images[5]) + len(images[5]) // 2)
    ds = catalog.open(copy, verify=verify)
    shard0 = load_manifest(copy).shards[0].frames
    for i in (0, shard0 - 1):
        with pytest.raises(ShardError, match=path.name):
            ds[i]
    assert ds[shard0]["frame_index"] == 0  # other shards still load


@pytest.mark.parametrize("verify", ["sha256", "checksums"])
def test_tampered_state_is_never_returned(copy, verify):
    path = _frames_path(copy, 1)
    metadata = pq.ParquetFile(path).metadata
    names = [metadata.schema.column(j).path for j in range(metadata.num_columns)]
    chunk = metadata.row_group(0).column(names.index("joint_angles.list.element"))
    _flip(path, chunk.data_page_offset + chunk.total_compressed_size - 10)
    ds = catalog.open(copy, verify=verify)
    with pytest.raises(ShardError, match=path.name):
        ds[load_manifest(copy).shards[0].frames]


@pytest.mark.parametrize("verify", ["sha256", "checksums"])
def test_tampered_episodes_file_is_named_at_open(copy, verify):
    path = copy / load_manifest(copy).shards[0].files["episodes"].path
    metadata = pq.ParquetFile(path).metadata
    chunk = metadata.row_group(0).column(0)
    _flip(path, chunk.data_page_offset + chunk.total_compressed_size - 5)
    with pytest.raises(ShardError, match=path.name):
        catalog.open(copy, verify=verify)


def test_sha256_catches_what_checksums_cannot(copy):
    """An edit outside any checksummed page (here the writer name in the footer) changes the file's
    sha256: the default mode refuses it; checksum mode reads the (still correct) arrays."""
    path = _frames_path(copy)
    data = path.read_bytes()
    _flip(path, data.rfind(b"parquet-cpp-arrow"))
    with pytest.raises(ShardError, match=rf"{path.name}.*sha256"):
        catalog.open(copy)[0]
    _, frames, images = make_episode(0)
    item = catalog.open(copy, verify="checksums")[0]
    np.testing.assert_array_equal(item["image"], _rgb(images[0]))
    np.testing.assert_array_equal(item["palm_pose"], frames.palm_pose[0])


def test_file_replaced_after_open_is_refused(copy):
    """The default mode hashes a frames file on its first use in a process, not at open."""
    ds = catalog.open(copy)
    other = copy.parent / "other"
    write_slice(other, episodes=EPISODES, shard_size=SHARD_SIZE, seed=8)
    path = _frames_path(copy)
    path.write_bytes(_frames_path(other).read_bytes())
    with pytest.raises(ShardError, match=rf"{path.name}.*(sha256|truncated|longer)"):
        ds[0]


def test_image_offsets_span_pages_and_row_groups(tmp_path):
    """Over 1024 frames of 64 px noise JPEGs: two row groups of several 1 MiB pages each."""
    from catalog.tables.pages import image_offsets
    from catalog.tables.parquet_io import DATA_PAGE_SIZE, read_frames

    root = tmp_path / "big"
    settings = {**SETTINGS, "resolution": 64}
    with ShardWriter(root, 0, 50, settings) as writer:
        for i in range(50):
            spec = make_spec(i)
            rng = np.random.default_rng([11, i])
            frames = make_frames(spec, rng)
            writer.add_episode(spec, frames, make_images(frames.num_frames, rng, size=64))
    write_manifest(root, Manifest.create("linear-fast", 7, settings, [writer.record], code=CODE))
    path = _frames_path(root)
    metadata = pq.ParquetFile(path).metadata
    assert metadata.num_row_groups == 2
    assert metadata.row_group(0).column(4).total_compressed_size > 3 * DATA_PAGE_SIZE
    stored = read_frames(path, ["image"]).column("image").to_pylist()
    import hashlib
    import os

    fd = os.open(path, os.O_RDONLY)
    try:
        hasher = hashlib.sha256()
        offsets, lengths = image_offsets(fd, str(path), metadata, hasher=hasher, size=path.stat().st_size)
        assert [os.pread(fd, n, o) for o, n in zip(offsets, lengths)] == stored
        assert hasher.hexdigest() == load_manifest(root).shards[0].files["frames"].sha256
    finally:
        os.close(fd)
    for verify in ("checksums", "sha256"):
        ds = catalog.open(root, verify=verify)
        for i in (0, 1023, 1024, len(ds) - 1):
            np.testing.assert_array_equal(ds[i]["image"], _rgb(stored[i]))
        np.testing.assert_array_equal(ds[1024]["palm_pose"], read_frames(path, ["palm_pose"]).column("palm_pose")[1024].values)


def test_null_values_in_a_hashed_frames_file_are_named(copy):
    """A frames file with a null ``action`` (written by another tool, with a manifest over it)
    raises ShardError naming the file and column, not a numpy reshape error."""
    import pyarrow as pa

    from catalog.store.hashing import sha256_file
    from catalog.store.records import FileRecord, ShardRecord
    from catalog.tables.parquet_io import writer_options
    from schemas.versions import SCHEMA_VERSION

    manifest = load_manifest(copy)
    shard = manifest.shards[0]
    path = copy / shard.files["frames"].path
    table = pq.read_table(path)
    column = table.column("action").combine_chunks()
    values = column.to_pylist()
    values[3] = None
    index = table.schema.get_field_index("action")
    table = table.set_column(index, pa.field("action", column.type, nullable=True), pa.array(values, column.type))
    schema = table.schema.with_metadata({"dyana.table": "frames", "dyana.schema_version": SCHEMA_VERSION})
    with pq.ParquetWriter(str(path), schema, **writer_options("frames")) as writer:
        writer.write_table(table.cast(schema))
    files = dict(shard.files)
    files["frames"] = FileRecord(shard.files["frames"].path, sha256_file(path), path.stat().st_size)
    shards = [ShardRecord(shard.episodes, shard.frames, files), *manifest.shards[1:]]
    write_manifest(copy, Manifest.create(manifest.slice, manifest.seed, dict(manifest.settings), shards, code=CODE))
    for verify in ("sha256", "checksums"):
        with pytest.raises(ShardError, match=rf"{path.name}.*'action'.*null"):
            catalog.open(copy, verify=verify)[0]


def test_non_finite_values_give_a_shard_error_for_stats(tmp_path):
    """Statistics over a shard holding a NaN cannot be stored as JSON: name the file and column
    instead of failing inside json.dumps."""
    spec, frames, images = make_episode(0)
    velocity = frames.object_velocity.copy()
    velocity[2, 1] = np.nan
    root = tmp_path / "nan"
    with ShardWriter(root, 0, 1, SETTINGS) as writer:
        writer.add_episode(spec, replace(frames, object_velocity=velocity), images)
    write_manifest(root, Manifest.create("linear-fast", 1, SETTINGS, [writer.record], code=CODE))
    with pytest.raises(ShardError, match=r"frames/000000-000000\.parquet: column 'object_velocity' holds non-finite"):
        _ = catalog.open(root).stats
    assert not (root / STATS_NAME).exists()


def test_images_of_another_size_than_the_settings_say_are_refused(tmp_path):
    """A manifest claiming 16 px (with a consistent hash) over 32 px images is not served."""
    root = tmp_path / "linear-fast"
    write_slice(root, episodes=2, settings={**SETTINGS, "resolution": 16})
    with pytest.raises(ShardError, match="is 32x32 px, catalog.json says 16"):
        catalog.open(root)[0]
