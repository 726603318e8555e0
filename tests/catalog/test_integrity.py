"""Standard readers open the shards; damaged files are reported by name."""

import shutil

import duckdb
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from catalog.store.atomic import temp_path
from catalog.store.manifest import Manifest, load_manifest, write_manifest
from catalog.tables.integrity import check_files, verify_files
from catalog.tables.mcap_reader import iter_messages, mcap_summary
from catalog.tables.parquet_io import check_parquet, read_frames
from catalog.tables.reader import open_folder
from schemas.errors import SettingsMismatch, ShardError
from schemas.tables import EPISODES_SCHEMA, FRAMES_SCHEMA


def _paths(slice_dir, shard=0):
    manifest = load_manifest(slice_dir)
    return {kind: slice_dir / f.path for kind, f in manifest.shards[shard].files.items()}


def _flip(path, offset):
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


def test_duckdb_reads_the_contract_columns(slice_dir):
    manifest = load_manifest(slice_dir)
    glob = f"{slice_dir}/frames/*.parquet"
    columns = duckdb.sql(f"DESCRIBE SELECT * FROM read_parquet('{glob}')").fetchall()
    assert [c[0] for c in columns] == FRAMES_SCHEMA.names
    types = dict((c[0], c[1]) for c in columns)
    assert types["episode_index"] == "BIGINT" and types["frame_index"] == "INTEGER" and types["image"] == "BLOB"
    assert types["joint_poses"].startswith("FLOAT[")
    rows = duckdb.sql(
        f"SELECT count(*), count(DISTINCT episode_index), max(len(joint_poses)) FROM read_parquet('{glob}')"
    ).fetchall()[0]
    assert rows == (manifest.frames, manifest.episodes, 90)
    query = f"SELECT timestamp FROM read_parquet('{glob}') WHERE episode_index = 2 AND frame_index = 7"
    stamp = duckdb.sql(query).fetchall()
    assert stamp == [(7 / 20,)]
    n = duckdb.sql(f"SELECT count(*) FROM read_parquet('{slice_dir}/episodes/*.parquet')").fetchall()[0][0]
    assert n == manifest.episodes
    (rows_only,) = duckdb.sql(f"SELECT count(*) FROM '{slice_dir}/frames/*.parquet'").fetchall()[0]
    assert rows_only == manifest.frames  # the table folder alone, nothing of the episodes table mixed in


def test_pyarrow_dataset_opens_each_table_folder(slice_dir):
    import pyarrow.dataset as ds

    manifest = load_manifest(slice_dir)
    frames = ds.dataset(slice_dir / "frames", format="parquet").to_table()
    assert frames.schema.equals(FRAMES_SCHEMA) and frames.num_rows == manifest.frames
    episodes = ds.dataset(slice_dir / "episodes", format="parquet").to_table()
    assert episodes.schema.equals(EPISODES_SCHEMA)
    assert episodes.column("episode_index").to_pylist() == list(range(manifest.episodes))


def test_pandas_reads_each_table_folder(slice_dir):
    import pandas as pd

    manifest = load_manifest(slice_dir)
    frames = pd.read_parquet(slice_dir / "frames")
    assert len(frames) == manifest.frames and list(frames.columns) == FRAMES_SCHEMA.names
    assert frames.groupby("episode_index").size().tolist() == [s for s in _frames_per_episode(slice_dir)]
    episodes = pd.read_parquet(slice_dir / "episodes")
    assert episodes["episode_id"].tolist() == [f"linear-fast:{i:06d}" for i in range(manifest.episodes)]


def _frames_per_episode(slice_dir):
    return open_folder(slice_dir).episodes(["num_frames"]).column("num_frames").to_pylist()


def test_intact_folder_verifies(slice_dir):
    manifest = verify_files(slice_dir, full=True)
    assert check_files(slice_dir, manifest) == []


def test_tampered_file_is_named(slice_dir):
    paths = _paths(slice_dir, 1)
    _flip(paths["mcap"], paths["mcap"].stat().st_size // 2)
    problems = check_files(slice_dir, load_manifest(slice_dir))
    assert [(p.path, p.kind) for p in problems] == [("mcap/000002-000003.mcap", "sha256")]
    with pytest.raises(ShardError, match=r"mcap/000002-000003\.mcap: content changed"):
        verify_files(slice_dir)


def test_truncated_missing_stray_and_unlisted_files(slice_dir):
    paths = _paths(slice_dir)
    paths["frames"].write_bytes(paths["frames"].read_bytes()[:-100])
    paths["episodes"].unlink()
    temp_path(slice_dir / "mcap" / "000004-000004.mcap", pid=999999).write_bytes(b"x")
    shutil.copy(paths["mcap"], slice_dir / "mcap" / "000009-000009.mcap")
    problems = check_files(slice_dir, load_manifest(slice_dir))
    assert [(p.path, p.kind) for p in problems] == [
        ("frames/000000-000001.parquet", "size"),
        ("episodes/000000-000001.parquet", "missing"),
        ("mcap/.000004-000004.mcap.tmp-999999", "stray-temp"),
        ("mcap/000009-000009.mcap", "unlisted"),
    ]
    assert "truncated" in problems[0].detail
    with pytest.raises(ShardError, match=r"frames/000000-000001\.parquet: truncated.*\(and 3 more problem\(s\)\)"):
        verify_files(slice_dir)


def test_sample_checks_k_whole_shards(slice_dir):
    manifest = load_manifest(slice_dir)
    paths = _paths(slice_dir, 0)
    _flip(paths["episodes"], 10)
    found = set()
    for seed in range(12):
        problems = check_files(slice_dir, manifest, sample=1, rng=np.random.default_rng(seed))
        found.add(tuple(p.path for p in problems))
    assert found == {(), ("episodes/000000-000001.parquet",)}
    assert len(check_files(slice_dir, manifest, sample=10)) == 1
    with pytest.raises(ShardError, match="--sample"):
        check_files(slice_dir, manifest, sample=0)


def test_readers_name_truncated_and_foreign_files(slice_dir, tmp_path):
    paths = _paths(slice_dir)
    cut = tmp_path / "cut.frames.parquet"
    cut.write_bytes(paths["frames"].read_bytes()[:-50])
    with pytest.raises(ShardError, match=r"cut\.frames\.parquet: not a readable Parquet file"):
        read_frames(cut)
    junk = tmp_path / "junk.parquet"
    junk.write_bytes(b"PAR1" + bytes(100))
    with pytest.raises(ShardError, match="junk.parquet: not a readable Parquet"):
        read_frames(junk)
    with pytest.raises(ShardError, match="missing.parquet: file is missing"):
        read_frames(tmp_path / "missing.parquet")
    with pytest.raises(ShardError, match="table kind is 'episodes', expected 'frames'"):
        read_frames(paths["episodes"])

    table = read_frames(paths["frames"])
    pq.write_table(table.drop_columns(["image"]), tmp_path / "noimage.parquet")
    with pytest.raises(ShardError, match="noimage.parquet: missing column 'image'"):
        read_frames(tmp_path / "noimage.parquet")
    assert read_frames(tmp_path / "noimage.parquet", ["episode_index"]).num_rows == table.num_rows
    wrong = table.set_column(2, pa.field("timestamp", pa.float32()), table["timestamp"].cast(pa.float32()))
    pq.write_table(wrong, tmp_path / "wrong.parquet")
    with pytest.raises(ShardError, match="column 'timestamp' has type float, expected double"):
        read_frames(tmp_path / "wrong.parquet")
    check_parquet(paths["episodes"], "episodes", rows=2)
    with pytest.raises(ShardError, match="has 2 rows, expected 3"):
        check_parquet(paths["episodes"], "episodes", rows=3)


def test_page_checksums_catch_corrupt_image_bytes(slice_dir, tmp_path):
    paths = _paths(slice_dir)
    meta = pq.ParquetFile(paths["frames"]).metadata
    image = meta.row_group(0).column(FRAMES_SCHEMA.get_field_index("image"))
    bad = tmp_path / "bad.frames.parquet"
    shutil.copy(paths["frames"], bad)
    _flip(bad, image.data_page_offset + image.total_compressed_size // 2)
    read_frames(bad, ["episode_index"])  # other columns stay readable
    with pytest.raises(ShardError, match=r"bad\.frames\.parquet: corrupt Parquet data"):
        read_frames(bad, ["image"])


def test_mcap_damage_is_named(slice_dir, tmp_path):
    paths = _paths(slice_dir)
    data = paths["mcap"].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ShardError, match=r"cut\.mcap: not a readable MCAP file"):
        mcap_summary(cut)
    with pytest.raises(ShardError, match=r"cut\.mcap: not a readable MCAP file"):
        list(iter_messages(cut, decode=False))
    flipped = tmp_path / "flipped.mcap"
    flipped.write_bytes(data)
    _flip(flipped, len(data) // 3)
    with pytest.raises(ShardError, match=r"flipped\.mcap"):
        list(iter_messages(flipped, decode=False))


def test_manifest_over_wrong_files_is_caught_by_the_structural_check(slice_dir):
    """sha256 and size match (the manifest was written over bad files): the content check names them."""
    from dataclasses import replace

    from catalog.store.hashing import sha256_file
    from catalog.store.manifest import Manifest, write_manifest

    manifest = load_manifest(slice_dir)
    paths = _paths(slice_dir)
    shutil.copy(paths["episodes"], paths["frames"])
    shard = manifest.shards[0]
    files = dict(shard.files)
    files["frames"] = replace(files["frames"], sha256=sha256_file(paths["frames"]), size=paths["frames"].stat().st_size)
    shards = (replace(shard, files=files),) + manifest.shards[1:]
    write_manifest(slice_dir, Manifest.create(manifest.slice, manifest.seed, manifest.settings, shards, manifest.code))
    problems = check_files(slice_dir, load_manifest(slice_dir))
    assert [(p.path, p.kind) for p in problems] == [("frames/000000-000001.parquet", "unreadable")]
    assert "table kind is 'episodes', expected 'frames'" in problems[0].detail


def test_a_re_hashed_other_fps_is_refused_naming_catalog_json(slice_dir):
    """fps 30 written into catalog.json and re-hashed: the files still match their records,
    so only the settings check can refuse it, naming the manifest (before any rebuild)."""
    manifest = load_manifest(slice_dir)
    edited = Manifest.create(manifest.slice, manifest.seed, {**manifest.settings, "fps": 30}, manifest.shards,
                             code=manifest.code, stats=manifest.stats)
    write_manifest(slice_dir, edited)
    with pytest.raises(SettingsMismatch, match=r"catalog\.json: settings fps is 30"):
        verify_files(slice_dir)
