"""How fast `catalog.open` serves frames, against bare JPEG decoding of the same bytes.

Writes a realistic slice to a temporary folder with the catalog's shard writer
(``--episodes`` episodes of ``--frames`` frames, ``--resolution`` px JPEGs at quality
90 of rendered-like content: a smooth gradient, a table, a moving ball and a hand
blob; ``--shard-size`` episodes per shard), then times, best of ``--repeats``:

- decode: ``cv2.imdecode`` of every frame's JPEG bytes, already in memory (the issue's
  baseline); ``sj_*``: the same with ``simplejpeg.decode_jpeg`` to RGB, the decoder the
  loader uses (the same pixels, ~30% faster), so ``*_vs_simplejpeg`` ratios are what the
  loader adds beyond its own decoder;
- random: ``catalog.open`` then ``ds[i]`` over a seeded random permutation of all frames;
- sequential: ``catalog.open`` then ``ds[i]`` for i in order;
- windows: ``history=1, action_horizon=16`` items in the random and in sequential order,
  against bare decoding of the frames each window holds (two per item, one at an
  episode's first frame), in the same order: the ratio is what a window costs beyond
  the decodes it needs (``window_overhead_us`` per item). In sequential order the
  loader reuses the previous window's frame, so it can beat decoding every window;
  ``ratio_windows_sequential_frames`` compares it with decoding each frame once;
- resize: ``resize=resolution // 2`` with ``resample="jpeg"`` (reduced-size decoding)
  and with the default ``"area"`` (full decode + ``cv2.INTER_AREA``), random order,
  against the full bare decode (``ratio_resize``: above 1 is faster than decoding in
  full) and against bare reduced decoding (``cv2.IMREAD_REDUCED_COLOR_2``);
- torch (with torch installed and ``--torch-workers`` > 0): epochs of
  ``DataLoader(ds.torch(), batch_size=32, shuffle=True, num_workers=W,
  persistent_workers=True)`` in wall-clock time, against this one process's bare decode
  in wall-clock time (``torch_speedup``, best epoch after the first, which starts the
  workers; ``torch_first_epoch_speedup`` includes it); ``torch_ready_speedup`` is the same
  DataLoader over copies of one ready-made item (no reading, no decoding): the ceiling
  that DataLoader's own transport (collate into fresh shared memory, one file descriptor
  passed per tensor) sets. ``torch_fast_speedup`` (``torch_fast_first_epoch_speedup``,
  ``torch_fast_ready_speedup``) is the same for ``ds.torch().loader(batch_size=32,
  shuffle=True, num_workers=W, persistent_workers=True)`` (:mod:`catalog.loader.torch_batches`:
  the same batches, each built by its worker in one reused shared-memory slab); None
  where the code predates it.

Each loader pass uses a freshly opened dataset, so it pays what a DataLoader worker
pays every epoch: loading each shard on first use (sha256 of the file, the float
columns, the image page walk). ``catalog.open`` itself (manifest, episodes tables,
index), done once per training run in the main process, is timed separately
(``open_ms``); one untimed open beforehand pays the one-off module imports. A second
pass over the same dataset (``warm_*``: shards already loaded, as in later epochs of
persistent workers) shows the steady state. RSS is sampled 10% into an extra random
pass and at its end (growth should be ~0: the caches are bounded and hold no image bytes).

Times other than torch's are this process's CPU time (``time.process_time``, every
thread counted), so that other jobs on a shared machine skew the ratios less;
everything measured runs on one thread, so on an idle machine they equal wall-clock
time. The load average (``os.getloadavg``) is recorded at the start and the end.

Prints a summary, then as its last line one JSON object with ``decode_fps``,
``random_fps``, ``sequential_fps``, ``ratio_random``, ``ratio_sequential`` (loader
fps / decode fps, first pass), ``warm_ratio_random``, ``warm_ratio_sequential``,
``ratio_windows_random``, ``ratio_windows_sequential``,
``ratio_windows_sequential_frames``, ``window_overhead_us``, ``ratio_resize``,
``ratio_resize_reduced``, ``ratio_resize_area``, ``torch_speedup``,
``torch_first_epoch_speedup``, ``torch_ready_speedup``, ``torch_fast_speedup``,
``torch_fast_first_epoch_speedup``, ``torch_fast_ready_speedup``, ``frames``, ``rss_mb``, ``rss_growth_mb``, ``open_ms``,
``verify``, ``load_average``.
Tiny check: ``python benchmarks/dataloader.py --episodes 8 --repeats 1 --json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import bench_setup  # noqa: F401  (puts the repository first on sys.path)
import cv2
import numpy as np
import simplejpeg

import catalog  # noqa: E402
from catalog.store.manifest import CodeInfo, Manifest, write_manifest  # noqa: E402
from catalog.tables.parquet_io import read_frames  # noqa: E402
from catalog.tables.shard import ShardWriter  # noqa: E402
from schemas.frames import EpisodeFrames  # noqa: E402
from schemas.motion import LineToken, Motion  # noqa: E402
from schemas.scene import GRASP_FRAMES  # noqa: E402
from schemas.spec import EpisodeSpec  # noqa: E402
from schemas.tables import ARRAY_WIDTHS  # noqa: E402
from schemas.versions import DATASET_VERSION  # noqa: E402


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
    settings = {
        "fps": 20, "resolution": resolution, "image_format": "jpeg", "jpeg_quality": 90,
        "dataset_version": DATASET_VERSION,
    }
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


def _window_rows(ds) -> list[list[int]]:
    """Per position of a history=1 dataset, the distinct positions (frames) its window holds."""
    rows = []
    for k in range(len(ds.episodes)):
        frames = ds.episode_frames(k)
        rows.extend([[p] if p == frames[0] else [p - 1, p] for p in frames])
    return rows


def _open(root: Path, **kwargs):
    """``catalog.open``; ``resample`` dropped (and reported) where the code predates it."""
    try:
        return catalog.open(root, **kwargs), kwargs.get("resample")
    except TypeError:
        kwargs.pop("resample", None)
        return catalog.open(root, **kwargs), None


class _Ready:
    """Copies of one ready item, as many as the dataset has frames: what DataLoader's own
    transport (collate into shared memory, passing it to the main process) costs alone."""

    def __init__(self, ds) -> None:
        self.item, self.n = ds[0], len(ds)

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, index: int):
        return {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in self.item.items()}


def _torch_epochs(root: Path, verify: str, workers: int, epochs: int) -> dict[str, list[float]] | None:
    """Wall seconds of each epoch of a shuffled map-style DataLoader (persistent workers), over
    the dataset and over ready-made items (``ready``), and of ``ds.torch().loader`` over both
    (``fast``, ``fast_ready``; skipped where ``catalog.loader.torch_batches`` does not exist)."""
    try:
        import torch
    except ImportError:
        return None
    ds = catalog.open(root, verify=verify)
    times: dict[str, list[float]] = {}
    try:
        from catalog.loader.torch_batches import torch_loader
    except ImportError:
        torch_loader = None
    runs = [("loader", ds.torch()), ("ready", _Ready(ds))]
    if torch_loader is not None:
        runs += [("fast", catalog.open(root, verify=verify)), ("fast_ready", _Ready(ds))]
    for name, dataset in runs:
        if name.startswith("fast"):
            loader = torch_loader(
                dataset, batch_size=32, shuffle=True, num_workers=workers, persistent_workers=True, seed=0
            )
        else:
            loader = torch.utils.data.DataLoader(
                dataset, batch_size=32, shuffle=True, num_workers=workers, persistent_workers=True,
                generator=torch.Generator().manual_seed(0),
            )
        for _ in range(epochs):
            start = time.perf_counter()
            for _batch in loader:
                pass
            times.setdefault(name, []).append(time.perf_counter() - start)
        del loader
    return times


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--shard-size", type=int, default=16)
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--verify", choices=("sha256", "checksums"), default="sha256")
    parser.add_argument("--torch-workers", type=int, default=2, help="0 skips the torch DataLoader epochs")
    parser.add_argument("--torch-epochs", type=int, default=6)
    parser.add_argument("--json", action="store_true", help="print the JSON summary line last")
    args = parser.parse_args(argv)
    load_start = os.getloadavg()

    with tempfile.TemporaryDirectory(prefix="dyana-dataloader-") as tmp:
        root = Path(tmp) / "linear-fast"
        manifest = build(root, args.episodes, args.frames, args.shard_size, args.resolution)
        jpegs = []
        for shard in manifest.shards:
            column = read_frames(root / shard.files["frames"].path, ["image"]).column("image")
            jpegs.extend(np.frombuffer(b, dtype=np.uint8) for b in column.to_pylist())
        n = len(jpegs)
        order = np.random.default_rng(0).permutation(n).tolist()
        half = args.resolution // 2
        window_rows = _window_rows(catalog.open(root, verify=args.verify))
        needs = {
            "windows_random": [r for i in order for r in window_rows[i]],
            "windows_sequential": [r for rows in window_rows for r in rows],
        }

        def decode() -> None:
            for buffer in jpegs:
                cv2.imdecode(buffer, cv2.IMREAD_COLOR)

        def decode_rows(rows, flags=cv2.IMREAD_COLOR) -> None:
            for r in rows:
                cv2.imdecode(jpegs[r], flags)

        def sj_decode_rows(rows, side: int = 0) -> None:
            for r in rows:
                simplejpeg.decode_jpeg(jpegs[r], colorspace="RGB", min_height=side, min_width=side)

        def opened(**kwargs):
            start = time.perf_counter()
            ds, resample = _open(root, verify=args.verify, **kwargs)
            if not kwargs:
                best["open"] = min(best["open"], time.perf_counter() - start)
            if "resample" in kwargs:
                used["resample"] = resample
            return ds

        def load(ds, positions) -> None:
            for i in positions:
                ds[i]

        windows = {"history": 1, "action_horizon": 16}
        loader_passes = {
            "random": ({}, order),
            "sequential": ({}, range(n)),
            "windows_random": (windows, order),
            "windows_sequential": (windows, range(n)),
            "resize": ({"resize": half, "resample": "jpeg"}, order),
            "resize_area": ({"resize": half}, order),
        }
        bare = {
            "decode": decode,
            "decode_random": lambda: decode_rows(order),
            "decode_reduced": lambda: decode_rows(order, cv2.IMREAD_REDUCED_COLOR_2),
            **{f"decode_{name}": (lambda rows=rows: decode_rows(rows)) for name, rows in needs.items()},
            "sj_decode": lambda: sj_decode_rows(range(n)),
            "sj_decode_random": lambda: sj_decode_rows(order),
            "sj_decode_windows_random": lambda: sj_decode_rows(needs["windows_random"]),
            "sj_decode_reduced": lambda: sj_decode_rows(order, half),
        }
        names = (*bare, *loader_passes, *(f"warm_{name}" for name in loader_passes), "decode_wall", "open")
        best = dict.fromkeys(names, np.inf)
        used: dict[str, str | None] = {}
        load(opened(), range(min(n, 8)))  # one-off import costs (pyarrow.compute, ...)
        for _ in range(args.repeats):
            for name, fn in bare.items():
                best[name] = min(best[name], _time(fn))
            start = time.perf_counter()
            decode()
            best["decode_wall"] = min(best["decode_wall"], time.perf_counter() - start)
            for name, (kwargs, positions) in loader_passes.items():
                fresh = opened(**kwargs)

                def run(fresh=fresh, positions=positions):
                    return load(fresh, positions)

                best[name] = min(best[name], _time(run))
                best[f"warm_{name}"] = min(best[f"warm_{name}"], _time(run))
        resample = used.get("resample")
        epochs = _torch_epochs(root, args.verify, args.torch_workers, args.torch_epochs) if args.torch_workers else None

        ds = catalog.open(root, verify=args.verify)
        warm = max(1, n // 10)
        for i in order[:warm]:
            ds[i]
        rss_warm = _rss_mb()
        for i in order[warm:]:
            ds[i]
        rss_end = _rss_mb()
        ds.close()

    fps = {name: n / best[name] for name in names if name != "open"}

    def ratio(name: str, baseline: str) -> float:
        return round(best[baseline] / best[name], 3)

    def speedup(name: str) -> float | None:
        """Bare decode wall time / the best epoch after the first (which starts the workers)."""
        if not epochs or name not in epochs:
            return None
        return round(best["decode_wall"] / min(epochs[name][1:] or epochs[name]), 3)

    result = {
        "decode_fps": round(fps["decode"], 1),
        "random_fps": round(fps["random"], 1),
        "sequential_fps": round(fps["sequential"], 1),
        "ratio_random": ratio("random", "decode"),
        "ratio_sequential": ratio("sequential", "decode"),
        "warm_ratio_random": ratio("warm_random", "decode"),
        "warm_ratio_sequential": ratio("warm_sequential", "decode"),
        "ratio_random_same_order": ratio("random", "decode_random"),
        "simplejpeg_decode_fps": round(fps["sj_decode"], 1),
        "ratio_random_vs_simplejpeg": ratio("random", "sj_decode_random"),
        "ratio_sequential_vs_simplejpeg": ratio("sequential", "sj_decode"),
        "warm_ratio_random_vs_simplejpeg": ratio("warm_random", "sj_decode_random"),
        "ratio_windows_random_vs_simplejpeg": ratio("windows_random", "sj_decode_windows_random"),
        "ratio_resize_vs_simplejpeg_reduced": ratio("resize", "sj_decode_reduced"),
        "windows_fps": round(fps["windows_random"], 1),
        "ratio_windows_random": ratio("windows_random", "decode_windows_random"),
        "ratio_windows_sequential": ratio("windows_sequential", "decode_windows_sequential"),
        "ratio_windows_sequential_frames": ratio("windows_sequential", "decode"),
        "warm_ratio_windows_random": ratio("warm_windows_random", "decode_windows_random"),
        "window_overhead_us": round((best["windows_random"] - best["decode_windows_random"]) / n * 1e6, 1),
        "resize_fps": round(fps["resize"], 1),
        "resample": resample,
        "ratio_resize": ratio("resize", "decode_random"),
        "ratio_resize_reduced": ratio("resize", "decode_reduced"),
        "ratio_resize_area": ratio("resize_area", "decode_random"),
        "torch_workers": args.torch_workers if epochs else 0,
        "torch_speedup": speedup("loader"),
        "torch_first_epoch_speedup": round(best["decode_wall"] / epochs["loader"][0], 3) if epochs else None,
        "torch_ready_speedup": speedup("ready"),
        "torch_fast_speedup": speedup("fast"),
        "torch_fast_first_epoch_speedup": (
            round(best["decode_wall"] / epochs["fast"][0], 3) if epochs and "fast" in epochs else None
        ),
        "torch_fast_ready_speedup": speedup("fast_ready"),
        "frames": n,
        "rss_mb": round(rss_end, 1),
        "rss_growth_mb": round(rss_end - rss_warm, 2),
        "open_ms": round(best["open"] * 1e3, 2),
        "verify": args.verify,
        "load_average": [round(v, 2) for v in (*load_start, *os.getloadavg())],
    }
    mean_bytes = sum(len(b) for b in jpegs) / max(n, 1)
    print(
        f"{n} frames ({args.episodes} episodes, {len(manifest.shards)} shards, {args.resolution} px, "
        f"{mean_bytes / 1024:.1f} KiB/JPEG), best of {args.repeats}, load average "
        f"{' '.join(f'{v:.2f}' for v in load_start)} at the start:"
    )
    print(f"  bare cv2.imdecode  {fps['decode']:9.1f} fps")
    print(
        f"  bare simplejpeg    {fps['sj_decode']:9.1f} fps  (the loader's decoder; loader vs it: random "
        f"{result['ratio_random_vs_simplejpeg']:.3f}, sequential {result['ratio_sequential_vs_simplejpeg']:.3f}, "
        f"warm random {result['warm_ratio_random_vs_simplejpeg']:.3f}, windows random "
        f"{result['ratio_windows_random_vs_simplejpeg']:.3f}, resize vs its reduced decode "
        f"{result['ratio_resize_vs_simplejpeg_reduced']:.3f})"
    )
    for name, label in (("random", "random ds[i]"), ("sequential", "sequential ds[i]")):
        print(
            f"  {label:<18} {fps[name]:9.1f} fps  ({fps[name] / fps['decode']:.3f} of decode) first pass, "
            f"{fps['warm_' + name]:9.1f} fps ({fps['warm_' + name] / fps['decode']:.3f}) once the shards are loaded"
        )
    print(
        f"  windows h=1 a=16   {fps['windows_random']:9.1f} fps  ({result['ratio_windows_random']:.3f} of decoding "
        f"their frames) random, {fps['windows_sequential']:9.1f} fps ({result['ratio_windows_sequential']:.3f}; "
        f"{result['ratio_windows_sequential_frames']:.3f} of decoding each frame once) sequential; "
        f"{result['window_overhead_us']:.1f} us/item beyond the decodes"
    )
    print(
        f"  resize {half} px      {fps['resize']:9.1f} fps  ({result['ratio_resize']:.3f} of a full decode, "
        f"{result['ratio_resize_reduced']:.3f} of a bare reduced decode; resample={resample}), "
        f"area {fps['resize_area']:9.1f} fps ({result['ratio_resize_area']:.3f})"
    )
    if epochs:
        print(
            f"  torch {args.torch_workers} workers    epochs {', '.join(f'{n / t:.0f}' for t in epochs['loader'])} fps "
            f"wall vs {n / best['decode_wall']:.0f} fps bare decode in one process: {result['torch_speedup']:.2f}x "
            f"(first epoch {result['torch_first_epoch_speedup']:.2f}x); ready-made items "
            f"{', '.join(f'{n / t:.0f}' for t in epochs['ready'])} fps: {result['torch_ready_speedup']:.2f}x"
        )
        if "fast" in epochs:
            print(
                f"  ds.torch().loader  epochs {', '.join(f'{n / t:.0f}' for t in epochs['fast'])} fps: "
                f"{result['torch_fast_speedup']:.2f}x (first epoch {result['torch_fast_first_epoch_speedup']:.2f}x); "
                f"ready-made items {', '.join(f'{n / t:.0f}' for t in epochs['fast_ready'])} fps: "
                f"{result['torch_fast_ready_speedup']:.2f}x"
            )
    print(f"  catalog.open       {best['open'] * 1e3:9.2f} ms (once per training run, not timed above)")
    print(f"  RSS {rss_end:.1f} MB, growth over 90% of a random pass {result['rss_growth_mb']:+.2f} MB")
    print(f"  load average at the end {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    if args.json:
        print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
