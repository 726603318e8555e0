"""Beyond one machine: a Dask cluster across hosts that share no filesystem, with object
storage as the only common place (tests/hosts.py: a network namespace and a private disk
per host). Hosts: ``s3`` (moto's S3 server), ``sched`` (``dask scheduler``), ``wa`` and
``wb`` (``dask worker``, one single-threaded worker each), ``drv`` and ``drv2`` (drivers),
``pol`` (``pipeline serve``: a GPU box serving the policy to the CPU hosts that render).

Checked: the workers write the shards straight to the store (the driver's disk never
holds one); a build whose worker host is killed mid-shard finishes on the other with the
local build's hash; a driver killed mid-build resumes on another host from the store
alone (shards already recorded there are not written again: the bucket keeps object
versions) to the same hash; an eval whose policy is served from its own host survives
both kills in one run and has the local eval's hash.
Marked ``multihost`` (not in the default run; ``.ci/run`` runs it explicitly).
"""

from __future__ import annotations

import json
import re
import sys
import time
from pathlib import Path

import pytest

from pipeline.jobs.build import build
from pipeline.jobs.evaluate import evaluate
from tests.hosts import Hosts, missing_tools

pytestmark = pytest.mark.multihost

BIN = Path(sys.executable).parent
BUCKET = "dyana-multihost"
EPISODES, EVAL_EPISODES, RESOLUTION = 6, 6, 32
BUILD = ["build", "--slice", "linear-fast", "--episodes", str(EPISODES), "--shard-size", "1",
         "--resolution", str(RESOLUTION)]
EVAL = ["eval", "--policy", "ws://{pol}:8765", "--slice", "test-1k", "--episodes", str(EVAL_EPISODES),
        "--shard-size", "1", "--resolution", str(RESOLUTION)]
SECRET = "multihost-secret-never-logged"

#: Run on a host: the bucket's objects under a prefix, with their versions (JSON on stdout).
LIST = r"""
import json, sys, fsspec
fs = fsspec.filesystem("s3", version_aware=True)
root = sys.argv[1]
out = {}
for name in (fs.find(root) if fs.exists(root) else []):
    versions = fs.object_version_info(name)
    out[name[len(root) + 1:]] = {"versions": len(versions), "catalog": None, "state": None}
    if name.endswith("/catalog.json"):
        out[name[len(root) + 1:]]["catalog"] = json.loads(fs.cat_file(name))["hash"]
    if name.endswith("/.build-state.json"):
        out[name[len(root) + 1:]]["state"] = json.loads(fs.cat_file(name))["shards"]
print(json.dumps(out))
"""
MAKE_BUCKET = r"""
import sys, fsspec
fs = fsspec.filesystem("s3")
fs.mkdir(sys.argv[1])
fs.make_bucket_versioned(sys.argv[1])
"""


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    pytest.importorskip("moto.server", reason="moto[server] is not installed")
    pytest.importorskip("s3fs", reason="s3fs is not installed")
    why = missing_tools()
    if why:
        pytest.skip(why)
    logs = tmp_path_factory.mktemp("hostlogs")
    hosts = Hosts(logs)
    try:
        for name in ("s3", "sched", "wa", "wb", "drv", "drv2", "pol"):
            hosts.add(name)
        at = {name: host.address for name, host in hosts.hosts.items()}
        base = {"PATH": f"{BIN}:/usr/local/bin:/usr/bin:/bin", "PYTHONUNBUFFERED": "1", "LANG": "C.UTF-8"}
        store = {**base, "AWS_ACCESS_KEY_ID": "multihost", "AWS_SECRET_ACCESS_KEY": SECRET,
                 "AWS_DEFAULT_REGION": "us-east-1", "AWS_ENDPOINT_URL": f"http://{at['s3']}:5000"}
        s3 = hosts.start("s3", [str(BIN / "python"), "-m", "moto.server", "-H", at["s3"], "-p", "5000"], base, "s3.log")
        sched = hosts.start("sched", [str(BIN / "dask"), "scheduler", "--host", at["sched"], "--port", "8786",
                                      "--no-dashboard"], base, "sched.log")
        pol = hosts.start("pol", [str(BIN / "pipeline"), "serve", "--policy", "predictive", "--host", at["pol"],
                                  "--port", "8765"], base, "pol.log")
        hosts.wait_for_log("s3.log", r"Running on http", s3, 60)
        hosts.wait_for_log("sched.log", r"Scheduler at", sched, 60)
        made = hosts.run("drv", [str(BIN / "python"), "-c", MAKE_BUCKET, BUCKET], store, 60)
        assert made.returncode == 0, made.stderr
        cluster = Cluster(hosts, at, store)
        for wait in [cluster.start_worker(name) for name in ("wa", "wb")]:  # both start at once
            wait()
        hosts.wait_for_log("pol.log", r"serving \S+ on ws://", pol, 60)
        yield cluster
    finally:
        hosts.close()
        assert hosts.leftovers() == []


class Cluster:
    """The running hosts, and what the tests do with them."""

    def __init__(self, hosts: Hosts, at: dict[str, str], store: dict[str, str]) -> None:
        self.hosts, self.at, self.store = hosts, at, store

    def start_worker(self, name: str):
        """Start a Dask worker on host ``name``; returns the wait for its registration."""
        log = f"{name}-{time.monotonic_ns()}.log"
        proc = self.hosts.start(name, [str(BIN / "dask"), "worker", f"tcp://{self.at['sched']}:8786",
                                       "--host", self.at[name], "--nworkers", "1", "--nthreads", "1",
                                       "--no-dashboard", "--name", name], self.store, log)
        return lambda: self.hosts.wait_for_log(log, r"Registered to", proc, 90)

    def driver(self, name: str, argv: list[str], log: str):
        args = [arg.format(pol=self.at["pol"]) for arg in argv]
        return self.hosts.start(name, [str(BIN / "pipeline"), *args, "--scheduler", f"tcp://{self.at['sched']}:8786"],
                                self.store, log)

    def objects(self, prefix: str) -> dict[str, dict]:
        listed = self.hosts.run("drv2", [str(BIN / "python"), "-c", LIST, f"{BUCKET}/{prefix}"], self.store, 60)
        assert listed.returncode == 0, listed.stderr
        return json.loads(listed.stdout)

    def private_tmp(self, name: str) -> list[Path]:
        """What host ``name``'s own disk holds now (seen through one of its processes)."""
        for pid in self.hosts.pids(name):
            try:
                return list(Path(f"/proc/{pid}/root{self.hosts.disk}").rglob("*"))
            except OSError:
                continue
        return []

    def finish(self, proc, log: str, timeout: float = 300) -> str:
        try:
            proc.wait(timeout=timeout)
        except Exception:
            proc.kill()
            raise
        text = (self.hosts.logs / log).read_text(errors="replace")
        assert proc.returncode == 0, text[-3000:]
        assert SECRET not in text
        return text


@pytest.fixture(scope="module")
def local_build(tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    return build("linear-fast", out, episodes=EPISODES, shard_size=1, resolution=RESOLUTION, workers=0,
                 progress=False).hash


def _shards(objects: dict[str, dict]) -> set[str]:
    return {path for path in objects if path.split("/")[0] in ("frames", "episodes", "mcap")}


def _kill_worker_mid_shard(cluster: Cluster, proc, name: str) -> None:
    """Kill every process of worker host ``name`` while it writes a shard (its scratch
    folder exists); meanwhile the driver's disk never holds a shard file."""
    deadline = time.monotonic() + 240
    while True:
        assert proc.poll() is None, f"the job ended before worker {name} wrote a shard"
        assert time.monotonic() < deadline, f"worker {name} never started a shard"
        assert not [p for p in cluster.private_tmp("drv") if p.suffix in (".parquet", ".mcap")]
        if any(p.name.startswith("dyana-shard-") for p in cluster.private_tmp(name)):
            break
        time.sleep(0.05)
    assert cluster.hosts.kill(name)


def test_a_worker_host_killed_mid_shard_and_the_build_has_the_local_hash(cluster, local_build):
    proc = cluster.driver("drv", [*BUILD, "--out", f"s3://{BUCKET}/a"], "build-a.log")
    _kill_worker_mid_shard(cluster, proc, "wb")
    out = cluster.finish(proc, "build-a.log")
    objects = cluster.objects("a/linear-fast")
    assert objects["catalog.json"]["catalog"] == local_build, out
    assert len(_shards(objects)) == 3 * EPISODES and ".build-state.json" not in objects
    assert f"(hash {local_build[:16]})" in out
    cluster.start_worker("wb")()  # back for the next tests


def _kill_driver_after_two_shards(cluster: Cluster, proc, prefix: str) -> list[str]:
    """Kill host ``drv`` once its own state (on its private disk) records two shards; the
    files of the shards the store's state then lists."""
    deadline = time.monotonic() + 240
    while True:
        assert proc.poll() is None and time.monotonic() < deadline, "the job ended before two shards"
        states = [p for p in cluster.private_tmp("drv") if p.name == ".build-state.json"]
        try:
            if states and len(json.loads(states[0].read_text())["shards"]) >= 2:
                break
        except (OSError, ValueError):
            pass
        time.sleep(0.05)
    cluster.hosts.kill("drv")  # its second shard's record may or may not have reached the store
    before = cluster.objects(prefix)
    return [file["path"] for shard in before[".build-state.json"]["state"] for file in shard["files"].values()]


def _check_resumed(out: str, recorded: list[str], objects: dict[str, dict], shards: int, verb: str) -> None:
    """The resumed job kept exactly the shards the store's state listed (each object written once)."""
    found = re.search(rf"resuming: (\d+) of (\d+) shards already {verb}", out)
    assert found and (int(found.group(1)), int(found.group(2))) == (len(recorded) // 3, shards), out
    assert 1 <= len(recorded) // 3 < shards
    assert len(_shards(objects)) == 3 * shards and ".build-state.json" not in objects
    assert all(objects[path]["versions"] == 1 for path in recorded), (objects, recorded)


def test_a_driver_killed_mid_build_resumes_on_another_host(cluster, local_build):
    proc = cluster.driver("drv", [*BUILD, "--out", f"s3://{BUCKET}/b"], "build-b.log")
    recorded = _kill_driver_after_two_shards(cluster, proc, "b/linear-fast")
    out = cluster.finish(cluster.driver("drv2", [*BUILD, "--out", f"s3://{BUCKET}/b"], "build-b2.log"), "build-b2.log")
    objects = cluster.objects("b/linear-fast")
    assert objects["catalog.json"]["catalog"] == local_build, out
    _check_resumed(out, recorded, objects, EPISODES, "built")


def test_an_eval_with_the_policy_on_its_own_host_survives_both_kills_with_the_local_hash(cluster, tmp_path):
    """The policy served by ``pipeline serve`` on host ``pol`` to the workers; worker host
    ``wb`` killed mid-shard, then the driver killed and the run resumed on ``drv2``."""
    local = evaluate("predictive", "test-1k", tmp_path / "run", episodes=EVAL_EPISODES, resolution=RESOLUTION,
                     shard_size=1, workers=0, progress=False, summary=False)
    proc = cluster.driver("drv", [*EVAL, "--out", f"s3://{BUCKET}/eval"], "eval.log")
    _kill_worker_mid_shard(cluster, proc, "wb")
    recorded = _kill_driver_after_two_shards(cluster, proc, "eval")
    out = cluster.finish(cluster.driver("drv2", [*EVAL, "--out", f"s3://{BUCKET}/eval"], "eval2.log"), "eval2.log")
    objects = cluster.objects("eval")
    assert objects["catalog.json"]["catalog"] == local.hash, out
    _check_resumed(out, recorded, objects, EVAL_EPISODES, "evaluated")
