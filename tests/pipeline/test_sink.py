"""Where a shard task writes (pipeline.jobs.sink): a folder in place, or a URL from a scratch
folder of the worker's own host, each file uploaded whole, nothing after a failure."""

from __future__ import annotations

import pickle
import socket
from pathlib import Path

import pytest

from pipeline.jobs.sink import ShardSink
from schemas.errors import SpecError, StorageError
from tests.s3_server import s3_server

BUCKET = "dyana-sink"


@pytest.mark.parametrize("bad", ["", "relative/out", 3])
def test_a_sink_is_an_absolute_path_or_a_url(bad):
    with pytest.raises(SpecError, match="shard sink"):
        ShardSink(bad)


def test_a_folder_sink_is_the_folder_itself_by_its_absolute_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    sink = ShardSink.folder("out")
    assert sink.location == str(tmp_path / "out") and not sink.remote
    assert pickle.loads(pickle.dumps(sink)) == sink  # sent with every Dask task
    with sink.writing() as folder:
        assert folder == tmp_path / "out"


@pytest.fixture(scope="module")
def server():
    with s3_server(BUCKET) as env:
        yield env


def _objects(prefix: str) -> dict[str, bytes]:
    import fsspec

    fs = fsspec.filesystem("s3", skip_instance_cache=True)
    root = f"{BUCKET}/{prefix}"
    return {name[len(root) + 1:]: fs.cat_file(name) for name in fs.find(root)}


def test_a_url_sink_uploads_each_finished_file_and_leaves_no_scratch(server, tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)  # TMPDIR is read again
    sink = ShardSink(f"s3://{BUCKET}/run")
    with sink.writing() as folder:
        assert folder.parent == tmp_path  # on the worker's own disk
        (folder / "frames").mkdir()
        (folder / "frames" / "000000-000002.parquet").write_bytes(b"frames")
        (folder / "frames" / ".000002-000004.parquet.tmp-1").write_bytes(b"a temp")
    assert _objects("run") == {"frames/000000-000002.parquet": b"frames"}
    assert list(tmp_path.iterdir()) == []


class Failed(Exception):
    pass


def test_a_url_sink_uploads_nothing_of_a_task_that_fails(server, tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    with pytest.raises(Failed), ShardSink(f"s3://{BUCKET}/failed").writing() as folder:
        (folder / "episodes.parquet").write_bytes(b"whole, but its shard failed")
        raise Failed
    assert _objects("failed") == {}
    assert list(tmp_path.iterdir()) == []


def test_a_worker_that_cannot_reach_the_store_fails_before_any_work(tmp_path, monkeypatch):
    pytest.importorskip("s3fs")
    import s3fs

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    for key, value in {"AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}", "AWS_ACCESS_KEY_ID": "k",
                       "AWS_SECRET_ACCESS_KEY": "s", "AWS_MAX_ATTEMPTS": "1", "AWS_DEFAULT_REGION": "us-east-1",
                       "AWS_CONFIG_FILE": str(tmp_path / "none"), "AWS_SHARED_CREDENTIALS_FILE": str(tmp_path / "none")}.items():
        monkeypatch.setenv(key, value)
    s3fs.S3FileSystem.clear_instance_cache()
    entered: list[Path] = []
    try:
        with pytest.raises(StorageError, match=f"^s3://{BUCKET}/nowhere: cannot reach the object store"):
            with ShardSink(f"s3://{BUCKET}/nowhere").writing() as folder:
                entered.append(folder)
    finally:
        s3fs.S3FileSystem.clear_instance_cache()
    assert entered == []
