"""ShardWriter: round trip, determinism and atomicity of the three shard files."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from catalog.store.atomic import find_stray_temps
from catalog.store.hashing import sha256_file
from catalog.tables import parquet_io
from catalog.tables.parquet_io import column_to_numpy, read_episodes, read_frames
from catalog.tables.shard import ShardWriter
from schemas.errors import ShardError
from schemas.motion import Motion
from schemas.spec import EpisodeSpec
from schemas.tables import (
    EPISODES_SCHEMA,
    FRAMES_SCHEMA,
    ROLLOUT_EPISODES_SCHEMA,
    STATE_COLUMNS,
)
from tests.shard_files import shard_names

from .conftest import SETTINGS, make_episode, make_frames, make_images, make_spec

REPO = Path(__file__).resolve().parents[2]


def _write(root, episodes=(0, 1, 2), first=0, end=3, seed=0):
    with ShardWriter(root, first, end, SETTINGS) as writer:
        for i in episodes:
            writer.add_episode(*make_episode(i, seed))
    return writer.record


def _file_bytes(root, record):
    return {kind: (root / f.path).read_bytes() for kind, f in record.files.items()}


def test_round_trip_states_exact_and_images_equal(tmp_path):
    record = _write(tmp_path)
    assert record.episodes == (0, 3)
    assert record.files["frames"].path == "frames/000000-000002.parquet"
    assert record.files["episodes"].path == "episodes/000000-000002.parquet"
    assert record.files["mcap"].path == "mcap/000000-000002.mcap"
    for f in record.files.values():
        assert sha256_file(tmp_path / f.path) == f.sha256
        assert (tmp_path / f.path).stat().st_size == f.size

    frames_table = read_frames(tmp_path / record.files["frames"].path)
    assert frames_table.schema.equals(FRAMES_SCHEMA)
    assert frames_table.num_rows == record.frames
    episodes_table = read_episodes(tmp_path / record.files["episodes"].path)
    assert episodes_table.schema.equals(EPISODES_SCHEMA)
    start = 0
    for row, i in enumerate(range(3)):
        spec, frames, images = make_episode(i)
        n = frames.num_frames
        part = frames_table.slice(start, n)
        start += n
        assert part["episode_index"].to_pylist() == [i] * n
        assert part["frame_index"].to_pylist() == list(range(n))
        assert part["timestamp"].to_pylist() == [f / 20 for f in range(n)]
        assert part["phase"].to_pylist() == frames.phase_names
        assert part["image"].to_pylist() == images
        for name in (*STATE_COLUMNS, "action"):
            got = column_to_numpy(part[name])
            assert got.dtype == np.float32 and np.array_equal(got, getattr(frames, name)), name
        assert np.array_equal(column_to_numpy(part["fingertip_distance"]), frames.fingertip_distance)

        ep = episodes_table.slice(row, 1).to_pylist()[0]
        assert EpisodeSpec.from_json(ep["spec"]) == spec
        assert Motion.from_json(ep["tokens"]) == spec.motion
        assert np.array_equal(np.array(ep["grasp_angles"], np.float32), frames.grasp_angles)
        expected = {
            "episode_index": i, "episode_id": spec.episode_id, "slice": spec.slice, "motion_type": "linear",
            "object": spec.object, "rolling": spec.rolling, "hand": spec.hand, "rollout_format": spec.rollout_format,
            "intercept_setting": "fast", "observe_frames": spec.observe_frames, "intercept_frame": spec.intercept_frame,
            "num_frames": spec.num_frames, "seed": 7, "spec_hash": spec.spec_hash, "text": spec.text,
        }
        assert {k: ep[k] for k in expected} == expected
        assert ep["object_size"] == np.float32(spec.object_size) and ep["intercept_time_s"] == np.float32(0.5)
    assert start == frames_table.num_rows


def test_selected_columns_only(tmp_path):
    record = _write(tmp_path, episodes=(0,), end=1)
    table = read_frames(tmp_path / record.files["frames"].path, ["frame_index", "palm_pose"])
    assert table.column_names == ["frame_index", "palm_pose"]
    with pytest.raises(ShardError, match="'nope' is not a column"):
        read_frames(tmp_path / record.files["frames"].path, ["nope"])


def test_same_content_gives_identical_bytes(tmp_path):
    a = _write(tmp_path / "a")
    b = _write(tmp_path / "elsewhere" / "b")
    assert a == b
    assert _file_bytes(tmp_path / "a", a) == _file_bytes(tmp_path / "elsewhere" / "b", b)
    c = _write(tmp_path / "c", seed=1)
    assert all(c.files[k].sha256 != a.files[k].sha256 for k in ("frames", "mcap"))


def test_identical_bytes_in_a_fresh_process(tmp_path):
    """A different interpreter (other hash seed, other cwd) writes the same bytes."""
    here = _write(tmp_path / "here")
    script = textwrap.dedent(
        f"""
        import sys
        sys.path.insert(0, {str(REPO)!r})
        from tests.catalog.test_shard import _write
        _write({str(tmp_path / "there")!r})
        """
    )
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    subprocess.run([sys.executable, "-c", script], check=True, cwd=tmp_path, env=env, timeout=120)
    assert _file_bytes(tmp_path / "here", here) == _file_bytes(tmp_path / "there", here)


def test_fixed_row_groups_whatever_the_batching(tmp_path, monkeypatch):
    monkeypatch.setattr(parquet_io, "ROW_GROUP_ROWS", 16)
    tables = []
    for i in range(3):
        _, frames, images = make_episode(i)
        tables.append(parquet_io.frames_table(i, frames, images))
    whole = pa.concat_tables(tables)
    parquet_io.write_table(tmp_path / "one.parquet", whole, "frames")
    writer = parquet_io.TableWriter(tmp_path / "many.parquet", "frames")
    for t in tables:
        for start in range(0, t.num_rows, 7):
            writer.write(t.slice(start, 7))
    writer.close()
    assert (tmp_path / "one.parquet").read_bytes() == (tmp_path / "many.parquet").read_bytes()
    meta = pq.ParquetFile(tmp_path / "one.parquet").metadata
    sizes = [meta.row_group(i).num_rows for i in range(meta.num_row_groups)]
    assert sizes[:-1] == [16] * (len(sizes) - 1) and 0 < sizes[-1] <= 16 and sum(sizes) == whole.num_rows


def test_pinned_parquet_metadata(tmp_path):
    record = _write(tmp_path, episodes=(0,), end=1)
    meta = pq.ParquetFile(tmp_path / record.files["frames"].path).metadata
    assert set(meta.metadata) == {b"ARROW:schema", b"dyana.table", b"dyana.schema_version"}
    assert meta.metadata[b"dyana.table"] == b"frames"
    columns = {meta.row_group(0).column(i).path_in_schema: meta.row_group(0).column(i) for i in range(meta.num_columns)}
    assert columns["image"].compression == "UNCOMPRESSED" and not columns["image"].is_stats_set
    assert columns["object_pose.list.element"].compression == "ZSTD"
    assert columns["episode_index"].is_stats_set
    assert [c.column_index for c in meta.row_group(0).sorting_columns] == [0, 1]


def test_exception_inside_with_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError, match="render failed"):
        with ShardWriter(tmp_path, 0, 3, SETTINGS) as writer:
            writer.add_episode(*make_episode(0))
            assert find_stray_temps(tmp_path), "writes go to temp names"
            assert not (tmp_path / "mcap" / "000000-000002.mcap").exists()
            raise RuntimeError("render failed")
    assert shard_names(tmp_path) == []


def test_missing_episode_fails_finish_and_leaves_nothing(tmp_path):
    with pytest.raises(ShardError, match=r"1 episode\(s\) of \[0, 3\) were not added: \[1\]"):
        _write(tmp_path, episodes=(0, 2))
    assert shard_names(tmp_path) == []


def test_order_and_range_are_enforced(tmp_path):
    writer = ShardWriter(tmp_path, 10, 13, SETTINGS).start()
    try:
        writer.add_episode(*make_episode(11))
        with pytest.raises(ShardError, match="order must increase"):
            writer.add_episode(*make_episode(10))
        with pytest.raises(ShardError, match=r"outside \[10, 13\)"):
            writer.add_episode(*make_episode(13))
        spec, frames, images = make_episode(12)
        with pytest.raises(ShardError, match="images for"):
            writer.add_episode(spec, frames, images[:-1])
        with pytest.raises(ShardError, match="not a jpeg image"):
            writer.add_episode(spec, frames, [b"\x89PNG\r\n\x1a\n"] * len(images))
        with pytest.raises(ShardError, match="rollout shards only"):
            writer.add_episode(spec, frames, images, policy="p", status="ok")
        short = make_frames(spec, np.random.default_rng(0), num_frames=spec.num_frames - 1)
        with pytest.raises(ShardError, match="the spec says"):
            writer.add_episode(spec, short, make_images(short.num_frames, np.random.default_rng(0)))
        writer.add_episode(spec, frames, images)
        with pytest.raises(ShardError, match=r"\[10\]"):
            writer.finish()
    finally:
        writer.abort()
    assert shard_names(tmp_path) == []


def test_rollout_shard_has_policy_status_error(tmp_path):
    rng = np.random.default_rng(3)
    with ShardWriter(tmp_path, 0, 2, SETTINGS, rollout=True) as writer:
        spec = make_spec(0)
        frames = make_frames(spec, rng)
        writer.add_episode(spec, frames, make_images(frames.num_frames, rng), policy="scripted", status="ok")
        spec = make_spec(1)
        cut = make_frames(spec, rng, num_frames=5)
        with pytest.raises(ShardError, match="exactly when status is 'error'"):
            writer.add_episode(spec, cut, make_images(5, rng), policy="scripted", status="error")
        writer.add_episode(spec, cut, make_images(5, rng), policy="scripted", status="error", error="NaN action")
    table = read_episodes(tmp_path / writer.record.files["episodes"].path)
    assert table.schema.equals(ROLLOUT_EPISODES_SCHEMA)
    assert table.select(["policy", "status", "error"]).to_pylist() == [
        {"policy": "scripted", "status": "ok", "error": ""},
        {"policy": "scripted", "status": "error", "error": "NaN action"},
    ]
    assert writer.record.frames == make_spec(0).num_frames + 5


def test_failed_write_caught_inside_with_still_leaves_nothing(tmp_path):
    """A write error swallowed inside the ``with`` must not leave temp files behind
    (nor let the block end as if the shard had been written)."""
    with pytest.raises(ShardError, match="failed to write; the shard was discarded"):
        with ShardWriter(tmp_path, 0, 1, SETTINGS) as writer:

            def disk_full(table):
                raise OSError("no space left on device")

            writer._frames_writer.write = disk_full
            with pytest.raises(OSError, match="no space"):
                writer.add_episode(*make_episode(0))
    assert find_stray_temps(tmp_path) == []
    assert shard_names(tmp_path) == []
    assert writer.record is None


def test_failure_while_renaming_leaves_no_partial_shard(tmp_path, monkeypatch):
    """If the last of the three renames fails, the two already renamed must not stay behind."""
    from catalog.store import atomic

    real_commit = atomic.commit
    calls = []

    def flaky_commit(temp, final):
        calls.append(final)
        if len(calls) == 3:
            raise OSError("I/O error")
        real_commit(temp, final)

    monkeypatch.setattr(atomic, "commit", flaky_commit)
    with pytest.raises(OSError, match="I/O error"):
        _write(tmp_path)
    assert len(calls) == 3
    assert shard_names(tmp_path) == []


class _FullDiskStream:
    """A file whose final flush fails as on a full disk (every close raises ENOSPC)."""

    def __init__(self, real):
        self.real = real

    def __getattr__(self, name):
        return getattr(self.real, name)

    def close(self):
        self.real.close()
        raise OSError(28, "No space left on device")


def test_a_full_disk_at_close_leaves_no_temporary_file(tmp_path):
    writer = ShardWriter(tmp_path, 0, 1, SETTINGS).start()
    writer.add_episode(*make_episode(0))
    writer._mcap_stream = _FullDiskStream(writer._mcap_stream)
    with pytest.raises(OSError, match="No space left"):
        writer.finish()
    assert find_stray_temps(tmp_path) == []
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []
