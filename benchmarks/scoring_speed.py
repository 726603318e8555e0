"""How long `scoring eval` takes on 1,000 recorded rollouts, against a bare baseline.

Writes a synthetic run (``--episodes`` rollouts of ``--frames`` frames in shards of
``--shard-size`` episodes, images of ``--image-bytes`` incompressible bytes, the
contract's tables written with the catalog's pinned Parquet writer and listed in a
manifest) to a temporary folder, or takes an existing run (``--run RUN``), then
times, best of ``--repeats``:

- baseline: pyarrow reading the very columns scoring needs from every shard, at the
  paths the manifest records (no checks);
- scoring: ``load_run`` (the reader's checks included) + ``score_run`` + ``report_dict``
  in this process: everything ``scoring eval RUN --json`` does but start and print, the
  hold test of every closed episode included (its memory of earlier calls cleared);
- command: ``scoring eval RUN --json`` as a fresh process, start-up and imports included.

Prints a summary, then one JSON line ``{"episodes", "frames", "shards", "seconds",
"read_seconds", "ratio", "cli_seconds", ...}`` (ratio = seconds / read_seconds).
Tiny check: ``python benchmarks/scoring_speed.py --episodes 20 --repeats 1``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_setup  # noqa: F401  (puts the repository first on sys.path)
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from catalog.store.hashing import sha256_file  # noqa: E402
from catalog.store.manifest import CodeInfo, Manifest, load_manifest, write_manifest  # noqa: E402
from catalog.store.records import FileRecord, ShardRecord, shard_paths  # noqa: E402
from catalog.tables.parquet_io import write_table  # noqa: E402
from generators import hold  # noqa: E402
from generators.recipe import spec_for  # noqa: E402
from schemas.scene import INTERCEPT_SECONDS, MOTION_TYPES  # noqa: E402
from schemas.tables import ARRAY_WIDTHS, FRAMES_SCHEMA, ROLLOUT_EPISODES_SCHEMA  # noqa: E402
from schemas.versions import DATASET_VERSION  # noqa: E402
from scoring.io import EPISODE_COLUMNS, FRAME_COLUMNS, ROLLOUT_COLUMNS, load_run  # noqa: E402
from scoring.report import report_dict, score_run  # noqa: E402


def _fixed(values: np.ndarray) -> pa.FixedSizeListArray:
    values = np.ascontiguousarray(values, dtype=np.float32)
    return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), values.shape[1])


def _shard_tables(rng: np.random.Generator, first: int, end: int, frames: int, image_bytes: int):
    """Frames and episodes tables of episodes [first, end): a palm that approaches a moving
    object with a per-episode skill, so that some episodes localize and grasp and some do not."""
    n = end - first
    observe = rng.integers(0, 15, n)
    t = np.arange(frames)
    episode = np.repeat(np.arange(first, end), frames)
    frame = np.tile(t, n).astype(np.int32)
    acting = frame >= np.repeat(observe, frames)
    start = rng.uniform([-3, 1.5], [3, 7.5], (n, 2))
    velocity = rng.uniform(-0.08, 0.08, (n, 2))
    obj_xz = start[:, None, :] + velocity[:, None, :] * t[None, :, None]
    skill = rng.uniform(0.3, 1.0, n)
    progress = np.clip((t[None, :] - observe[:, None]) / (frames - observe[:, None] - 8), 0.0, 1.0) * skill[:, None]
    rest = np.array([0.0, 0.5])
    palm_xz = rest + (obj_xz - rest) * progress[..., None] + rng.normal(0, 0.02, (n, frames, 2))
    palm = np.zeros((n, frames, 6), np.float32)
    palm[..., 0], palm[..., 1], palm[..., 2] = palm_xz[..., 0], 3.0 - 2.0 * progress, palm_xz[..., 1]
    obj = np.zeros((n, frames, 7), np.float32)
    obj[..., 0], obj[..., 1], obj[..., 2], obj[..., 6] = obj_xz[..., 0], 0.2, obj_xz[..., 1], 1.0
    grasp = rng.uniform(0.4, 1.4, (n, 15)).astype(np.float32)
    closing = np.clip((progress - 0.7) / 0.3, 0.0, 1.0)
    joints = (grasp[:, None, :] * closing[..., None]).astype(np.float32)
    tips = np.hypot(*(palm_xz - obj_xz).transpose(2, 0, 1)).astype(np.float32)

    rows = n * frames
    closed_phase = np.where(progress >= skill[:, None] * 0.999, "grasp", "approach").reshape(-1)
    phase = np.where(acting, closed_phase, "observe")
    image_pool = rng.bytes(image_bytes * 4)
    images = [image_pool[(i % 4) * image_bytes:(i % 4 + 1) * image_bytes] for i in range(rows)]
    columns = {
        "episode_index": pa.array(episode, pa.int64()),
        "frame_index": pa.array(frame),
        "timestamp": pa.array(frame / 20.0),
        "phase": pa.array(phase.tolist(), pa.string()),
        "image": pa.array(images, pa.binary()),
        "palm_pose": _fixed(palm.reshape(rows, 6)),
        "object_pose": _fixed(obj.reshape(rows, 7)),
        "joint_angles": _fixed(joints.reshape(rows, 15)),
        "fingertip_distance": pa.array(tips.reshape(-1)),
    }
    for name in ("object_velocity", "joint_poses", "keypoints", "action"):
        columns[name] = _fixed(np.zeros((rows, ARRAY_WIDTHS[name]), np.float32))
    frames_table = pa.Table.from_arrays([columns[f.name] for f in FRAMES_SCHEMA], schema=FRAMES_SCHEMA)

    index = np.arange(first, end)
    specs = [spec_for("test-1k", int(i)) for i in index]  # real specs: S_hold's hold test reads them
    status = np.where(rng.random(n) < 0.02, "error", "ok")
    values = {
        "episode_index": index,
        "episode_id": [f"test-1k:{i:06d}" for i in index],
        "slice": ["test-1k"] * n,
        "motion_type": [MOTION_TYPES[i % 3] for i in index],
        "tokens": ["[]"] * n,
        "object": [spec.object for spec in specs],
        "object_size": np.array([spec.object_size for spec in specs], np.float32),
        "rolling": [False] * n,
        "hand": [spec.hand for spec in specs],
        "rollout_format": ["observe-before-act"] * n,
        "intercept_setting": [list(INTERCEPT_SECONDS)[(i // 3) % 3] for i in index],
        "intercept_time_s": np.full(n, 1.0, np.float32),
        "observe_frames": observe.astype(np.int32),
        "intercept_frame": (observe + 20).astype(np.int32),
        "num_frames": np.full(n, frames, np.int32),
        "seed": np.full(n, 1),
        "spec_hash": ["0" * 64] * n,
        "text": [""] * n,
        "spec": [spec.to_json() for spec in specs],
        "policy": ["synthetic"] * n,
        "privileged": [False] * n,
        "status": status.tolist(),
        "error": ["policy raised" if s == "error" else "" for s in status],
    }
    arrays = [
        _fixed(grasp) if f.name == "grasp_angles" else pa.array(values[f.name], f.type) for f in ROLLOUT_EPISODES_SCHEMA
    ]
    return frames_table, pa.Table.from_arrays(arrays, schema=ROLLOUT_EPISODES_SCHEMA)


def write_synthetic_run(folder: Path, episodes: int, frames: int, image_bytes: int, shard_size: int, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    shards = []
    for first in range(0, episodes, shard_size):
        end = min(first + shard_size, episodes)
        paths = shard_paths(first, end)
        for path in paths.values():
            (folder / path).parent.mkdir(parents=True, exist_ok=True)
        frames_table, episodes_table = _shard_tables(rng, first, end, frames, image_bytes)
        write_table(folder / paths["frames"], frames_table, "frames")
        write_table(folder / paths["episodes"], episodes_table, "rollout_episodes")
        (folder / paths["mcap"]).write_bytes(b"")
        files = {k: FileRecord(p, sha256_file(folder / p), (folder / p).stat().st_size) for k, p in paths.items()}
        shards.append(ShardRecord((first, end), frames_table.num_rows, files))
    settings = {"dataset_version": DATASET_VERSION, "fps": 20, "resolution": 224, "image_format": "jpeg"}
    manifest = Manifest.create("test-1k", seed, settings, shards, code=CodeInfo("0.1.0", None), extra={"policy": "synthetic"})
    write_manifest(folder, manifest)
    return folder


def read_baseline(folder: Path) -> int:
    """Bare pyarrow: read the columns scoring needs from every shard, at the paths its
    manifest records (no hashing, no checks)."""
    rows = 0
    for shard in load_manifest(folder).shards:
        rows += pq.read_table(folder / shard.files["frames"].path, columns=list(FRAME_COLUMNS)).num_rows
        pq.read_table(folder / shard.files["episodes"].path, columns=list(EPISODE_COLUMNS + ROLLOUT_COLUMNS))
    return rows


def score(folder: Path) -> dict:
    """Score a run as a fresh ``scoring eval`` would: the hold tests this process remembers
    (:data:`generators.hold.MEMO`) are forgotten first, so each call pays its physics."""
    hold.MEMO.clear()
    return report_dict(score_run(load_run(folder)))


def best_of(repeats: int, fn, *args) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn(*args)
        best = min(best, time.perf_counter() - start)
    return best, result


def cli_seconds(folder: Path) -> float:
    """Wall seconds of ``scoring eval FOLDER --json`` as a fresh process: interpreter
    start-up, imports, loading, scoring and printing."""
    env = {**os.environ, "PYTHONPATH": bench_setup.ROOT}
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "scoring.cli", "eval", str(folder), "--json"], cwd=bench_setup.ROOT,
                   env=env, stdout=subprocess.DEVNULL, check=True)
    return time.perf_counter() - start


def measure(folder: Path, repeats: int) -> dict:
    """Best-of-``repeats`` seconds of the bare read, of scoring in this process and of the
    ``scoring eval`` command, on one run folder."""
    manifest = load_manifest(folder)
    read_seconds, rows = best_of(repeats, read_baseline, folder)
    seconds, result = best_of(repeats, score, folder)
    command = min(cli_seconds(folder) for _ in range(repeats))
    assert rows == manifest.frames and result["episodes"] == manifest.episodes
    return {
        "episodes": manifest.episodes,
        "frames": manifest.frames,
        "shards": len(manifest.shards),
        "seconds": round(seconds, 4),
        "read_seconds": round(read_seconds, 4),
        "ratio": round(seconds / read_seconds, 3),
        "cli_seconds": round(command, 4),
        "metrics": result["metrics"],
        "errors": result["errors"],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", metavar="RUN", help="time an existing run folder instead of a synthetic one")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--frames", type=int, default=70)
    parser.add_argument("--image-bytes", type=int, default=12_000, help="bytes per (incompressible) image")
    parser.add_argument("--shard-size", type=int, default=32, help="episodes per shard (pipeline eval's default)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    load = [round(v, 2) for v in os.getloadavg()]
    if args.run is not None:
        folder = Path(args.run)
        size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
        print(f"run: {folder}, {size / 1e6:.1f} MB on disk")
        out = measure(folder, args.repeats)
    else:
        with tempfile.TemporaryDirectory(prefix="dyana-scoring-bench-") as tmp:
            folder = Path(tmp) / "run"
            start = time.perf_counter()
            write_synthetic_run(folder, args.episodes, args.frames, args.image_bytes, args.shard_size, args.seed)
            write_seconds = time.perf_counter() - start
            size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
            print(f"run: synthetic, {size / 1e6:.1f} MB on disk (written in {write_seconds:.1f} s)")
            out = measure(folder, args.repeats)

    m = out.pop("metrics")
    print(f"{out['episodes']} episodes, {out['frames']} frames in {out['shards']} shards; "
          f"S_loc {m['S_loc']:.2f}%  S_gra {m['S_gra']:.2f}%  errors {out['errors']}")
    print(f"baseline read (same columns): {out['read_seconds']:.3f} s; scoring (load + metrics + report, "
          f"in process): {out['seconds']:.3f} s; ratio {out['ratio']:.2f}; "
          f"`scoring eval RUN --json` as a fresh process: {out['cli_seconds']:.3f} s")
    print(json.dumps({"benchmark": "scoring_speed", "run": args.run or "synthetic", **out,
                      "repeats": args.repeats, "load_average": load}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
