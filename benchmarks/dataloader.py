"""How fast `catalog.open` serves frames, against bare JPEG decoding of the same bytes.

Writes a realistic slice to a temporary folder with the catalog's shard writer
(``--episodes`` episodes of ``--frames`` frames, ``--resolution`` px JPEGs at quality
90 of rendered-like content: a smooth gradient, a table, a moving ball and a hand
blob; ``--shard-size`` episodes per shard), then times, best of ``--repeats``:

- decode: ``cv2.imdecode`` of every frame's JPEG bytes, already in memory;
- random: ``catalog.open`` then ``ds[i]`` over a seeded random permutation of all frames;
- sequential: ``catalog.open`` then ``ds[i]`` for i in order.

Each loader pass uses a freshly opened dataset, so it pays what a DataLoader worker
pays every epoch: loading each shard on first use (sha256 of the file, the float
columns, the image page walk). ``catalog.open`` itself (manifest, episodes tables,
index), done once per training run in the main process, is timed separately
(``open_ms``); one untimed open beforehand pays the one-off module imports. A second
pass over the same dataset (``warm_*``: shards already loaded, as in later epochs of
persistent workers) shows the steady state. RSS is sampled 10% into an extra random pass and at its end (growth should
be ~0: the caches are bounded and hold no image bytes).

Times are this process's CPU time (``time.process_time``, every thread counted), so
that other jobs on a shared machine skew the ratios less; everything measured runs on
one thread, so on an idle machine they equal wall-clock time.

Prints a summary, then as its last line one JSON object with ``decode_fps``,
``random_fps``, ``sequential_fps``, ``ratio_random``, ``ratio_sequential`` (loader
fps / decode fps, first pass) and ``warm_ratio_random``, ``warm_ratio_sequential``,
``frames``, ``rss_mb``, ``rss_growth_mb``, ``open_ms``, ``verify``.
Tiny check: ``python benchmarks/dataloader.py --episodes 8 --repeats 1 --json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import bench_setup  # noqa: F401  (puts the repository first on sys.path)
import cv2
import numpy as np

import catalog  # noqa: E402
from catalog.manifest import CodeInfo, Manifest, write_manifest  # noqa: E402
from catalog.parquet_io import read_frames  # noqa: E402
from catalog.shard import ShardWriter  # noqa: E402
from schemas.frames import EpisodeFrames  # noqa: E402
from schemas.motion import LineToken, Motion  # noqa: E402
from schemas.scene import GRASP_FRAMES  # noqa: E402
from schemas.spec import EpisodeSpec  # noqa: E402
from schemas.tables import ARRAY_WIDTHS  # noqa: E402


def _spec(index: int, frames: int) -> EpisodeSpec:
    motion = Motion.of(
        LineToken(
            start=(-1.0, 4.0), direction=0.3 + 0.01 * index, speed=0.5, acceleration=0.0, duration=frames / 20 + 1
        )
    )
    observe = 3 + index % 3
    return EpisodeSpec(
        slice="linear-fast",
        episode_index=index,
        seed=1,
        motion_type="linear",
        motion=motion,
        object="tennis_ball",
        object_size=1.0,
        hand="right",
        rollout_format="observe-before-act",
        intercept_setting="fast",
        observe_frames=observe,
        num_frames=max(frames, observe + 10 + GRASP_FRAMES + 1),
        text="grasp the moving tennis ball",
    )


def _frames(spec: EpisodeSpec, rng: np.random.Generator) -> EpisodeFrames:
    n = spec.num_frames
    phase = np.full(n, 3, dtype=np.int8)
    phase[: spec.intercept_frame + GRASP_FRAMES] = 2
    phase[: spec.intercept_frame] = 1
    phase[: spec.observe_frames] = 0

    def f32(*shape: int) -> np.ndarray:
        return rng.standard_normal(shape).astype(np.float32)

    pose = f32(n, 7)
    pose[:, 3:] /= np.linalg.norm(pose[:, 3:], axis=1, keepdims=True)
    widths = ARRAY_WIDTHS
    return EpisodeFrames(
        phase=phase,
        object_pose=pose,
        object_velocity=f32(n, widths["object_velocity"]),
        palm_pose=f32(n, 6),
        joint_angles=f32(n, 15),
        joint_poses=f32(n, 90),
        keypoints=f32(n, 36),
        action=f32(n, 18),
        fingertip_distance=np.abs(f32(n)),
        palm_distance=np.abs(f32(n)),
        grasp_angles=f32(15),
    )


def _images(n: int, size: int, rng: np.random.Generator) -> list[bytes]:
    """Rendered-like frames: a lit gradient backdrop, a table, a ball moving across, a hand blob."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    tint = rng.uniform(0.6, 1.0, 3)
    backdrop = np.stack([150 + 80 * x * tint[0], 160 + 60 * y * tint[1], 190 - 50 * y * tint[2]], -1)
    backdrop[int(0.55 * size) :] = [110, 90, 70]
    backdrop = backdrop.astype(np.uint8)
    start, velocity = rng.uniform(0.2, 0.8, 2) * size, rng.uniform(-0.01, 0.01, 2) * size
    color = tuple(int(c) for c in rng.integers(30, 230, 3))
    images = []
    for t in range(n):
        frame = backdrop.copy()
        cx, cy = (start + velocity * t).astype(int)
        cv2.circle(frame, (int(cx), int(cy) + size // 4), size // 14, color, -1, cv2.LINE_AA)
        hand = (size // 2 + t, size // 5 + t // 2)
        cv2.ellipse(frame, hand, (size // 9, size // 14), 15, 0, 360, (210, 170, 150), -1, cv2.LINE_AA)
        ok, encoded = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        images.append(encoded.tobytes())
    return images


def build(root: Path, episodes: int, frames: int, shard_size: int, resolution: int) -> Manifest:
    settings = {"fps": 20, "resolution": resolution, "image_format": "jpeg", "jpeg_quality": 90}
    records = []
    for first in range(0, episodes, shard_size):
        with ShardWriter(root, first, min(first + shard_size, episodes), settings) as writer:
            for i in range(first, min(first + shard_size, episodes)):
                rng = np.random.default_rng([1, i])
                spec = _spec(i, frames)
                writer.add_episode(spec, _frames(spec, rng), _images(spec.num_frames, resolution, rng))
        records.append(writer.record)
    manifest = Manifest.create("linear-fast", 1, settings, records, code=CodeInfo("0.1.0", None))
    write_manifest(root, manifest)
    return manifest


def _rss_mb() -> float:
    with open("/proc/self/status") as handle:
        for line in handle:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _time(fn) -> float:
    """CPU seconds of this process spent in ``fn`` (all its threads)."""
    start = time.process_time()
    fn()
    return time.process_time() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--shard-size", type=int, default=16)
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--verify", choices=("sha256", "checksums"), default="sha256")
    parser.add_argument("--json", action="store_true", help="print the JSON summary line last")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="dyana-dataloader-") as tmp:
        root = Path(tmp) / "linear-fast"
        manifest = build(root, args.episodes, args.frames, args.shard_size, args.resolution)
        jpegs = []
        for shard in manifest.shards:
            column = read_frames(root / shard.files["frames"].path, ["image"]).column("image")
            jpegs.extend(np.frombuffer(b, dtype=np.uint8) for b in column.to_pylist())
        n = len(jpegs)
        order = np.random.default_rng(0).permutation(n).tolist()

        def decode() -> None:
            for buffer in jpegs:
                cv2.imdecode(buffer, cv2.IMREAD_COLOR)

        def opened():
            start = time.perf_counter()
            ds = catalog.open(root, verify=args.verify)
            best["open"] = min(best["open"], time.perf_counter() - start)
            return ds

        def load(ds, positions) -> None:
            for i in positions:
                ds[i]

        passes = ("decode", "random", "sequential", "warm_random", "warm_sequential")
        best = dict.fromkeys((*passes, "open"), np.inf)
        load(opened(), range(min(n, 8)))  # one-off import costs (pyarrow.compute, ...)
        for _ in range(args.repeats):
            best["decode"] = min(best["decode"], _time(decode))
            for name, positions in (("random", order), ("sequential", range(n))):
                fresh = opened()
                def run(fresh=fresh, positions=positions):
                    return load(fresh, positions)

                best[name] = min(best[name], _time(run))
                best[f"warm_{name}"] = min(best[f"warm_{name}"], _time(run))

        ds = catalog.open(root, verify=args.verify)
        warm = max(1, n // 10)
        for i in order[:warm]:
            ds[i]
        rss_warm = _rss_mb()
        for i in order[warm:]:
            ds[i]
        rss_end = _rss_mb()
        ds.close()

    fps = {name: n / best[name] for name in passes}
    result = {
        "decode_fps": round(fps["decode"], 1),
        "random_fps": round(fps["random"], 1),
        "sequential_fps": round(fps["sequential"], 1),
        "ratio_random": round(fps["random"] / fps["decode"], 3),
        "ratio_sequential": round(fps["sequential"] / fps["decode"], 3),
        "warm_ratio_random": round(fps["warm_random"] / fps["decode"], 3),
        "warm_ratio_sequential": round(fps["warm_sequential"] / fps["decode"], 3),
        "frames": n,
        "rss_mb": round(rss_end, 1),
        "rss_growth_mb": round(rss_end - rss_warm, 2),
        "open_ms": round(best["open"] * 1e3, 2),
        "verify": args.verify,
    }
    mean_bytes = sum(len(b) for b in jpegs) / max(n, 1)
    print(
        f"{n} frames ({args.episodes} episodes, {len(manifest.shards)} shards, {args.resolution} px, "
        f"{mean_bytes / 1024:.1f} KiB/JPEG), best of {args.repeats}:"
    )
    print(f"  bare cv2.imdecode  {fps['decode']:9.1f} fps")
    for name, label in (("random", "random ds[i]"), ("sequential", "sequential ds[i]")):
        print(
            f"  {label:<18} {fps[name]:9.1f} fps  ({fps[name] / fps['decode']:.3f} of decode) first pass, "
            f"{fps['warm_' + name]:9.1f} fps ({fps['warm_' + name] / fps['decode']:.3f}) once the shards are loaded"
        )
    print(f"  catalog.open       {best['open'] * 1e3:9.2f} ms (once per training run, not timed above)")
    print(f"  RSS {rss_end:.1f} MB, growth over 90% of a random pass {result['rss_growth_mb']:+.2f} MB")
    if args.json:
        print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
