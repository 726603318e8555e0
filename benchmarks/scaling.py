"""Build scaling: throughput with 1 and 2 local Dask workers, the scheduler's and an upload's
cost per shard, and a projection of dyana-12m's wall time on 2 (this machine), 8, 32 and 128 cores.

Every build below is a real ``pipeline.jobs.build.build`` of the same episodes:

- ``in_process``: ``workers=0`` (no Dask), ``--shard-size S``: wall and CPU seconds per
  frame on one core (the CPU time is this process's, robust to other load).
- ``workers_1`` / ``workers_2``: a local cluster of 1 and 2 single-threaded worker
  processes, started by the build as ``pipeline build --workers N`` does, same shards:
  frames/s over wall time, cluster start-up included. ``parallel_efficiency`` =
  fps(2) / (2 fps(1)).
- ``cluster_start_s``: starting and closing such a cluster (1 worker) alone.
- ``scheduler_s_per_shard``: K episodes in K one-episode shards, on an already running
  1-worker cluster (``--scheduler ADDRESS``, warmed up by one build first) minus in this
  process, over K: what handing a shard to a worker and its result back costs.
- ``upload_s_per_shard``: the same K one-episode shards built in this process into
  ``s3://`` on a moto S3 server on 127.0.0.1 minus into a local folder, over K: what
  staging and uploading a shard's files costs on loopback (a real object store adds its
  network's latency and bandwidth).

The projection (``projection``), for P cores (one single-threaded worker each):

    T(P) = cluster_start_s + (F * cpu_s_per_frame + N * (scheduler_s_per_shard + upload_s_per_shard)) / (P * e)

with F and N dyana-12m's frames and shards at the default shard size (128), e the
efficiency measured at 2 workers. It assumes: that efficiency holds at P workers (the
machine's memory bandwidth, disk and the one scheduler keep up; it is measured on at most
2 cores), the per-frame cost of the measured slice is dyana-12m's average (its episodes'
frame counts come from the recipe; their scenes differ in cost), the per-shard cost is the
same at 128 episodes per shard as at one, uploads go at loopback speed and in parallel,
and no worker is lost or restarted.

    python benchmarks/scaling.py [--slice circular-medium] [--episodes 64] [--shard-size 8]
                                 [--tiny-shards 16] [--out benchmarks/results/scaling.json]
    python benchmarks/scaling.py --tiny --out /tmp/scaling.json   # a check that it runs (numbers meaningless)

Writes the JSON file (with the load average at start and end) and prints it as the last
line. Run it on a quiet machine, under the shared lock
(``flock /tmp/dyana-bench.lock python benchmarks/scaling.py``).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import bench_setup  # noqa: F401  (first: this checkout's code)

RESULT = Path(bench_setup.ROOT) / "benchmarks" / "results" / "scaling.json"
CORES = (2, 8, 32, 128)
TARGET = "dyana-12m"


def projection(measured: Mapping[str, float], frames: int, shards: int, cores: int) -> float:
    """T(P) of the module docstring: projected wall seconds of ``frames`` in ``shards`` on ``cores``."""
    if cores < 1 or frames < 0 or shards < 0:
        raise ValueError(f"cores must be >= 1 and frames, shards >= 0, got {cores}, {frames}, {shards}")
    efficiency = measured["parallel_efficiency"]
    if not 0 < efficiency:
        raise ValueError(f"parallel_efficiency must be > 0, got {efficiency}")
    per_shard = measured["scheduler_s_per_shard"] + (measured["upload_s_per_shard"] or 0.0)
    work = frames * measured["cpu_s_per_frame"] + shards * max(per_shard, 0.0)
    return measured["cluster_start_s"] + work / (cores * efficiency)


def target_size(shard_size: int) -> dict[str, int]:
    """dyana-12m's episodes, frames (from the recipe's episode tables) and shards at ``shard_size``."""
    from generators.recipe import episode_table
    from schemas.slices import get_slice

    episodes = frames = shards = 0
    for part in get_slice(TARGET).parts:
        table = episode_table(part)
        episodes += len(table)
        frames += int(table["num_frames"].sum())
        shards += math.ceil(len(table) / shard_size)
    return {"episodes": episodes, "frames": frames, "shards": shards, "shard_size": shard_size}


def _timed_build(slice_name: str, out: str | Path, **options: Any) -> dict[str, Any]:
    from pipeline.jobs.build import build

    wall, cpu = time.perf_counter(), time.process_time()
    manifest = build(slice_name, out, progress=False, overwrite=True, **options)
    return {"wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu, "frames": manifest.frames,
            "shards": len(manifest.shards), "hash": manifest.hash[:16]}


@contextlib.contextmanager
def _cluster(workers: int) -> Iterator[str]:
    """A local cluster as ``pipeline build`` starts one; yields the scheduler's address."""
    import dask
    from dask.distributed import Client, LocalCluster

    from pipeline.jobs.tasks import LEAN_WORKERS

    with dask.config.set(LEAN_WORKERS):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address="127.0.0.1:0", preload=["pipeline.jobs.tasks"])
        client = Client(cluster)
        try:
            yield cluster.scheduler_address
        finally:
            client.close()
            cluster.close()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextlib.contextmanager
def _s3(bucket: str) -> Iterator[bool]:
    """A moto S3 server on 127.0.0.1 with ``bucket``, its endpoint and credentials in the
    environment; yields False (and starts nothing) when moto or s3fs is not installed."""
    try:
        import moto.server  # noqa: F401
        import s3fs
    except ImportError:
        yield False
        return
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    env = {"AWS_ACCESS_KEY_ID": "dyana-bench", "AWS_SECRET_ACCESS_KEY": "dyana-bench-secret",
           "AWS_DEFAULT_REGION": "us-east-1", "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}"}
    saved = {key: os.environ.get(key) for key in env}
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise SystemExit("moto server did not start") from None
                time.sleep(0.1)
        os.environ.update(env)
        s3fs.S3FileSystem.clear_instance_cache()
        s3fs.S3FileSystem(skip_instance_cache=True).mkdir(bucket)
        yield True
    finally:
        s3fs.S3FileSystem.clear_instance_cache()
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        proc.terminate()
        proc.wait(timeout=10)


def _commit() -> str | None:
    from catalog.store.manifest import git_commit

    return git_commit(bench_setup.ROOT)


def measure(args: argparse.Namespace, scratch: Path) -> dict[str, Any]:
    common = {"episodes": args.episodes, "resolution": args.resolution}
    runs: dict[str, dict[str, Any]] = {}
    say = (lambda text: None) if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))

    say(f"in process: {args.episodes} episodes of {args.slice}, shards of {args.shard_size}")
    runs["in_process"] = _timed_build(args.slice, scratch / "p", workers=0, shard_size=args.shard_size, **common)
    for workers in (1, 2):
        say(f"{workers} local worker(s), same shards")
        runs[f"workers_{workers}"] = _timed_build(args.slice, scratch / f"w{workers}", workers=workers,
                                                  shard_size=args.shard_size, **common)
    hashes = {run["hash"] for run in runs.values()}
    if len(hashes) != 1:
        raise SystemExit(f"the builds differ ({sorted(hashes)}): the measurement is void")

    say("cluster start-up (1 worker)")
    start = time.perf_counter()
    with _cluster(1):
        pass
    cluster_start = time.perf_counter() - start

    tiny = {"episodes": args.tiny_shards, "resolution": args.resolution, "shard_size": 1}
    say(f"{args.tiny_shards} one-episode shards: in process, on a running 1-worker cluster")
    runs["tiny_in_process"] = _timed_build(args.slice, scratch / "tp", workers=0, **tiny)
    with _cluster(1) as address:
        _timed_build(args.slice, scratch / "warm", scheduler=address, **{**tiny, "episodes": 1})
        runs["tiny_scheduler"] = _timed_build(args.slice, scratch / "ts", scheduler=address, **tiny)
    upload = None
    with _s3("dyana-scaling") as served:
        if served:
            say(f"{args.tiny_shards} one-episode shards in process into s3:// on a moto server on loopback")
            runs["tiny_s3"] = _timed_build(args.slice, "s3://dyana-scaling/out", workers=0, **tiny)
            upload = (runs["tiny_s3"]["wall_s"] - runs["tiny_in_process"]["wall_s"]) / args.tiny_shards

    one, two = runs["workers_1"], runs["workers_2"]
    measured = {
        "cpu_s_per_frame": runs["in_process"]["cpu_s"] / runs["in_process"]["frames"],
        "wall_s_per_frame_in_process": runs["in_process"]["wall_s"] / runs["in_process"]["frames"],
        "fps_1_worker": one["frames"] / one["wall_s"],
        "fps_2_workers": two["frames"] / two["wall_s"],
        "parallel_efficiency": one["wall_s"] / (2 * two["wall_s"]),
        "cluster_start_s": cluster_start,
        "scheduler_s_per_shard": (runs["tiny_scheduler"]["wall_s"] - runs["tiny_in_process"]["wall_s"]) / args.tiny_shards,
        "upload_s_per_shard": upload,
    }
    target = target_size(128)
    return {
        "slice": args.slice,
        "episodes": args.episodes,
        "shard_size": args.shard_size,
        "tiny_shards": args.tiny_shards,
        "resolution": args.resolution,
        "tiny": args.tiny,
        "runs": runs,
        "measured": measured,
        "target": {"slice": TARGET, **target},
        "projection": {
            "model": "T(P) = cluster_start_s + (frames * cpu_s_per_frame + shards * (scheduler_s_per_shard + "
                     "upload_s_per_shard)) / (P * parallel_efficiency)",
            "hours": {str(p): projection(measured, target["frames"], target["shards"], p) / 3600 for p in CORES},
        },
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--slice", default="circular-medium")
    parser.add_argument("--episodes", type=int, default=64, help="episodes of the 1- and 2-worker builds (default: 64)")
    parser.add_argument("--shard-size", type=int, default=8, help="their shard size (default: 8)")
    parser.add_argument("--tiny-shards", type=int, default=16, help="one-episode shards of the overhead runs (default: 16)")
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--tiny", action="store_true",
                        help="4 episodes, shards of 2, 2 tiny shards, 64 px: checks the script runs; numbers meaningless")
    parser.add_argument("--out", type=Path, default=RESULT, help=f"the JSON file (default: {RESULT})")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    args = parser.parse_args(argv)
    if args.tiny:
        args.episodes, args.shard_size, args.tiny_shards, args.resolution = 4, 2, 2, 64
    if min(args.episodes, args.shard_size, args.tiny_shards) < 1 or args.episodes < 2 * args.shard_size:
        parser.error("--episodes, --shard-size and --tiny-shards must be >= 1, with at least two shards")
    load_start = os.getloadavg()
    started = datetime.datetime.now(datetime.UTC)
    with tempfile.TemporaryDirectory(prefix="dyana-scaling-") as scratch:
        result = measure(args, Path(scratch))
    record = {
        "date_utc": started.strftime("%Y-%m-%d %H:%M"),
        "commit": _commit(),
        "cores": os.cpu_count(),
        "load_average_start": [round(x, 2) for x in load_start],
        **result,
        "load_average_end": [round(x, 2) for x in os.getloadavg()],
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    print(json.dumps(record, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
