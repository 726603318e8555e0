"""A slice built into a real S3-API server on 127.0.0.1: it opens (ranged reads), verifies,
scores and resumes there, with the same bytes as a local build."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import catalog
from catalog.store.manifest import load_manifest
from catalog.store.storage import RangeReader
from pipeline.jobs.build import build
from tests.s3_server import s3_server
from tests.shard_files import shard_bytes

BIN = Path(sys.executable).parent
BUCKET = "dyana-test"
ARGS = ["--slice", "linear-fast", "--episodes", "6", "--shard-size", "2", "--resolution", "32", "--workers", "1"]



@pytest.fixture(scope="module")
def server():
    with s3_server(BUCKET) as env:
        yield env


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    build("linear-fast", out, episodes=6, shard_size=2, resolution=32, workers=0, progress=False)  # in this process:
    # the same bytes as any worker count, and the remote builds below run a Dask worker
    return out / "linear-fast"


def _cli(tool: str, *args: str, env: dict, staging: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / tool), *args], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **env, "DYANA_STAGING": str(staging)})


def _objects(prefix: str) -> dict[str, bytes]:
    import fsspec

    fs = fsspec.filesystem("s3")
    root = f"{BUCKET}/{prefix}"
    return {name[len(root) + 1:]: fs.cat_file(name) for name in fs.find(root)}


@pytest.fixture(scope="module")
def remote(server, local, tmp_path_factory):
    staging = tmp_path_factory.mktemp("staging")
    result = _cli("pipeline", "build", *ARGS, "--out", f"s3://{BUCKET}/data", "--quiet", env=server, staging=staging)
    assert result.returncode == 0, result.stderr
    return f"s3://{BUCKET}/data/linear-fast"


def test_a_remote_build_holds_the_local_builds_bytes_and_nothing_else(remote, local):
    objects = _objects("data/linear-fast")
    shards = {path: data for path, data in objects.items() if path.split("/")[0] in ("frames", "episodes", "mcap")}
    assert shards == shard_bytes(local)
    assert sorted(set(objects) - set(shards)) == ["catalog.json", "stats.json"]
    assert json.loads(objects["catalog.json"])["hash"] == load_manifest(local).hash


def test_the_dataloader_reads_items_with_ranged_requests(remote, local, monkeypatch):
    fetched: list[int] = []
    original = RangeReader.pread

    def counting(self, length, offset):
        fetched.append(length)
        return original(self, length, offset)

    monkeypatch.setattr(RangeReader, "pread", counting)
    there, here = catalog.open(remote), catalog.open(local)
    assert len(there) == len(here)
    for index in (0, len(here) // 2, len(here) - 1):
        a, b = there[index], here[index]
        assert a.keys() == b.keys()
        for key in a:
            assert np.array_equal(np.asarray(a[key]), np.asarray(b[key])), key
    frames_bytes = sum(f.size for s in load_manifest(local).shards for f in [s.files["frames"]])
    assert 0 < sum(fetched) < frames_bytes  # pages of the items, not whole files


@pytest.mark.slow(cover="tests/pipeline/test_object_store.py::test_a_remote_build_holds_the_local_builds_bytes_and_nothing_else")
def test_verify_and_scoring_work_on_the_url(remote, local, server, tmp_path):
    result = _cli("catalog", "verify", remote, "--quiet", env=server, staging=tmp_path)
    assert result.returncode == 0 and "3 rebuilt byte for byte" in result.stdout, result.stderr
    there = _cli("scoring", "eval", remote, "--json", env=server, staging=tmp_path)
    here = _cli("scoring", "eval", str(local), "--json", env=server, staging=tmp_path)
    assert there.returncode == 0, there.stderr
    assert json.loads(there.stdout)["metrics"] == json.loads(here.stdout)["metrics"]


@pytest.mark.slow(cover="tests/pipeline/test_object_store.py::test_a_second_job_on_one_url_from_this_machine_is_busy")
def test_a_rerun_is_up_to_date_and_another_job_is_refused(remote, server, tmp_path):
    again = _cli("pipeline", "build", *ARGS, "--out", f"s3://{BUCKET}/data", env=server, staging=tmp_path)
    assert again.returncode == 0 and again.stdout.startswith("up to date"), again.stderr
    other = [*ARGS[:-2], "--workers", "1", "--resolution", "48"]
    refused = _cli("pipeline", "build", *other, "--out", f"s3://{BUCKET}/data", env=server, staging=tmp_path)
    assert refused.returncode == 2 and "another job" in refused.stderr and refused.stderr.count("\n") == 1
    assert json.loads(_objects("data/linear-fast")["catalog.json"])["settings"]["resolution"] == 32


def test_a_killed_remote_build_resumes_on_another_machine(server, local, tmp_path):
    """Killed after its first shard reached the server; resumed with an empty staging folder
    (another machine): the finished shard is kept in the store (not downloaded, not rebuilt),
    and the bytes match. The workers upload the shards: no staging folder ever holds one."""
    import fsspec

    url = f"s3://{BUCKET}/killed"
    env = {**os.environ, **server, "DYANA_STAGING": str(tmp_path / "first")}
    proc = subprocess.Popen([str(BIN / "pipeline"), "build", *ARGS, "--out", url, "--quiet"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    fs = fsspec.filesystem("s3", skip_instance_cache=True)
    state = f"{BUCKET}/killed/linear-fast/.build-state.json"
    deadline = time.monotonic() + 240
    while not (fs.exists(state) and json.loads(fs.cat_file(state))["shards"]):
        assert proc.poll() is None and time.monotonic() < deadline, "the build ended before a shard was published"
        time.sleep(0.2)
        fs.invalidate_cache()
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    resumed = _cli("pipeline", "build", *ARGS, "--out", url, env=server, staging=tmp_path / "second")
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming: " in resumed.stderr
    assert not [p for p in tmp_path.rglob("*") if p.suffix in (".parquet", ".mcap")]
    objects = _objects("killed/linear-fast")
    assert {p: b for p, b in objects.items() if p.split("/")[0] in ("frames", "episodes", "mcap")} == shard_bytes(local)
    assert ".build-state.json" not in objects
    digest = hashlib.sha256(objects["catalog.json"]).hexdigest()
    assert digest and json.loads(objects["catalog.json"])["hash"] == load_manifest(local).hash


@pytest.mark.slow(cover="tests/pipeline/test_object_store.py::test_the_dataloader_reads_items_with_ranged_requests")
def test_view_replay_and_export_read_the_url(remote, server, tmp_path):
    view = _cli("pipeline", "view", remote, "--episode", "1", "--out", str(tmp_path / "e1.rrd"), env=server,
                staging=tmp_path)
    assert view.returncode == 0 and (tmp_path / "e1.rrd").stat().st_size > 0, view.stderr
    replay = _cli("pipeline", "replay", remote, env=server, staging=tmp_path)
    assert replay.returncode == 0 and "identical" in replay.stdout, replay.stderr
    export = _cli("catalog", "export", remote, "--out", str(tmp_path / "lerobot"), "--workers", "1", "--quiet",
                  env=server, staging=tmp_path)
    assert export.returncode == 0 and "6 episodes" in export.stdout, export.stderr


@pytest.mark.slow(cover="tests/pipeline/test_object_store.py::test_a_killed_remote_build_resumes_on_another_machine")
def test_staging_left_by_another_job_is_cleared_not_refused(server, tmp_path):
    from pipeline.jobs.object_store import staging_folder

    url = f"s3://{BUCKET}/fresh"
    os.environ["DYANA_STAGING"], saved = str(tmp_path), os.environ.get("DYANA_STAGING")
    try:
        stale = staging_folder(f"{url}/linear-fast")
    finally:
        if saved is None:
            del os.environ["DYANA_STAGING"]
        else:
            os.environ["DYANA_STAGING"] = saved
    stale.mkdir(parents=True)
    (stale / ".build-state.json").write_text(json.dumps({"identity": {"slice": "other"}, "shards": []}))
    result = _cli("pipeline", "build", *ARGS[:3], "2", *ARGS[4:], "--out", url, "--quiet", env=server, staging=tmp_path)
    assert result.returncode == 0, result.stderr
    # emptied (the other job's state gone); only its lock file stays, as lock files do
    assert [p.name for p in stale.iterdir()] == [".lock"] and "catalog.json" in _objects("fresh/linear-fast")


def test_a_second_job_on_one_url_from_this_machine_is_busy(tmp_path, monkeypatch):
    """The URL's lock (beside its staging folder) is taken before the store is touched, so no
    server is needed to see the refusal."""
    from pipeline.jobs.lock import FolderBusy, held
    from pipeline.jobs.object_store import staging_folder

    monkeypatch.setenv("DYANA_STAGING", str(tmp_path))
    url = f"s3://{BUCKET}/busy/linear-fast"  # the build writes OUT/<slice>
    staging = staging_folder(url)
    with held(staging.with_name(staging.name + ".lock"), url):
        with pytest.raises(FolderBusy, match=f"{url}: another process"):
            build("linear-fast", f"s3://{BUCKET}/busy", episodes=2, shard_size=2, resolution=32, workers=0,
                  progress=False)


# --- failures: one line naming the URL, exit 2, no traceback -------------------------------


def _closed_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]  # closed again when the block ends: nothing listens there


@pytest.fixture
def no_aws(monkeypatch, tmp_path):
    """A clean environment: no AWS_* variables, no credentials or config files, no instance
    metadata; one attempt per request (botocore retries 5 times by default: AWS_MAX_ATTEMPTS)."""
    s3fs = pytest.importorskip("s3fs")
    for key in [key for key in os.environ if key.startswith("AWS_")]:
        monkeypatch.delenv(key)
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "no-credentials"))
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "no-config"))
    monkeypatch.setenv("AWS_EC2_METADATA_DISABLED", "true")
    monkeypatch.setenv("AWS_MAX_ATTEMPTS", "1")
    monkeypatch.setenv("DYANA_STAGING", str(tmp_path / "staging"))
    s3fs.S3FileSystem.clear_instance_cache()  # filesystems made with another environment
    yield monkeypatch
    s3fs.S3FileSystem.clear_instance_cache()


URL = f"s3://{BUCKET}/nowhere"
COMMANDS = {
    "build": ("pipeline", ["build", *ARGS, "--out", URL]),
    "eval": ("pipeline", ["eval", "--policy", "predictive", "--slice", "test-1k", "--episodes", "2", "--workers", "1",
                          "--out", URL]),
    "verify": ("catalog", ["verify", URL]),
    "info": ("catalog", ["info", URL]),
    "export": ("catalog", ["export", URL, "--out", "exported"]),
}


def _main(program: str, argv: list[str]) -> int:
    from pipeline.cli import main as pipeline_main
    from pipeline.cli_catalog import main as catalog_main

    return (pipeline_main if program == "pipeline" else catalog_main)([*argv, "--quiet"] if argv[0] != "info" else argv)


@pytest.mark.parametrize("cause", ["unreachable", "no credentials"])
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_an_unusable_object_store_is_one_line_naming_the_url(no_aws, tmp_path, capsys, command, cause):
    port = _closed_port()
    no_aws.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{port}")
    if cause == "unreachable":
        no_aws.setenv("AWS_ACCESS_KEY_ID", "dyana-test")
        no_aws.setenv("AWS_SECRET_ACCESS_KEY", "dyana-test-secret")
    no_aws.chdir(tmp_path)
    program, argv = COMMANDS[command]
    assert _main(program, argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith(f"{program} {command}: error: {URL}")
    assert (f"cannot reach the object store at http://127.0.0.1:{port}" if cause == "unreachable"
            else "no credentials for the object store (set AWS_ACCESS_KEY_ID") in err


def test_catalog_open_on_an_unusable_store_raises_a_storage_error(no_aws):
    from schemas.errors import StorageError

    no_aws.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{_closed_port()}")
    with pytest.raises(StorageError, match=f"^{URL}: no credentials for the object store"):
        catalog.open(URL)


def test_a_missing_bucket_is_refused_before_any_shard_is_built(server, tmp_path, capsys, monkeypatch):
    from pipeline.cli import main

    monkeypatch.setenv("DYANA_STAGING", str(tmp_path))
    assert main(["build", *ARGS, "--out", "s3://no-such-bucket/data", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "s3://no-such-bucket/data/linear-fast: the bucket 'no-such-bucket' does not exist" in err
    assert not list(tmp_path.rglob("*.parquet"))  # checked before the first shard was built


def test_storage_options_given_in_a_upath_reach_every_shard_load(remote, local, server, no_aws):
    """Credentials and endpoint only in the UPath (no AWS_* variables): the folder opens and
    items load, their shards read with the same options."""
    from upath import UPath

    path = UPath(remote, key=server["AWS_ACCESS_KEY_ID"], secret=server["AWS_SECRET_ACCESS_KEY"],
                 endpoint_url=server["AWS_ENDPOINT_URL"], client_kwargs={"region_name": "us-east-1"})
    there, here = catalog.open(path), catalog.open(local)
    assert len(there) == len(here)
    for index in (0, len(here) - 1):
        a, b = there[index], here[index]
        assert all(np.array_equal(np.asarray(a[key]), np.asarray(b[key])) for key in a)
