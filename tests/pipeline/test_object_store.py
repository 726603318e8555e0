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
from catalog.manifest import load_manifest
from catalog.storage import RangeReader
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
    build("linear-fast", out, episodes=6, shard_size=2, resolution=32, workers=1, progress=False)
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


@pytest.mark.slow
def test_verify_and_scoring_work_on_the_url(remote, local, server, tmp_path):
    result = _cli("catalog", "verify", remote, "--quiet", env=server, staging=tmp_path)
    assert result.returncode == 0 and "3 rebuilt byte for byte" in result.stdout, result.stderr
    there = _cli("scoring", "eval", remote, "--json", env=server, staging=tmp_path)
    here = _cli("scoring", "eval", str(local), "--json", env=server, staging=tmp_path)
    assert there.returncode == 0, there.stderr
    assert json.loads(there.stdout)["metrics"] == json.loads(here.stdout)["metrics"]


@pytest.mark.slow
def test_a_rerun_is_up_to_date_and_another_job_is_refused(remote, server, tmp_path):
    again = _cli("pipeline", "build", *ARGS, "--out", f"s3://{BUCKET}/data", env=server, staging=tmp_path)
    assert again.returncode == 0 and again.stdout.startswith("up to date"), again.stderr
    other = [*ARGS[:-2], "--workers", "1", "--resolution", "48"]
    refused = _cli("pipeline", "build", *other, "--out", f"s3://{BUCKET}/data", env=server, staging=tmp_path)
    assert refused.returncode == 2 and "another job" in refused.stderr and refused.stderr.count("\n") == 1
    assert json.loads(_objects("data/linear-fast")["catalog.json"])["settings"]["resolution"] == 32


def test_a_killed_remote_build_resumes_on_another_machine(server, local, tmp_path):
    """Killed after its first shard reached the server; resumed with an empty staging folder
    (another machine): the finished shard is downloaded, not rebuilt, and the bytes match."""
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
    objects = _objects("killed/linear-fast")
    assert {p: b for p, b in objects.items() if p.split("/")[0] in ("frames", "episodes", "mcap")} == shard_bytes(local)
    assert ".build-state.json" not in objects
    digest = hashlib.sha256(objects["catalog.json"]).hexdigest()
    assert digest and json.loads(objects["catalog.json"])["hash"] == load_manifest(local).hash


@pytest.mark.slow
def test_view_replay_and_export_read_the_url(remote, server, tmp_path):
    view = _cli("pipeline", "view", remote, "--episode", "1", "--out", str(tmp_path / "e1.rrd"), env=server,
                staging=tmp_path)
    assert view.returncode == 0 and (tmp_path / "e1.rrd").stat().st_size > 0, view.stderr
    replay = _cli("pipeline", "replay", remote, env=server, staging=tmp_path)
    assert replay.returncode == 0 and "identical" in replay.stdout, replay.stderr
    export = _cli("catalog", "export", remote, "--out", str(tmp_path / "lerobot"), "--workers", "1", "--quiet",
                  env=server, staging=tmp_path)
    assert export.returncode == 0 and "6 episodes" in export.stdout, export.stderr


@pytest.mark.slow
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
