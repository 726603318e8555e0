"""The bridge to LeRobot: export speed and fidelity, and keyed loading speed, in one run.

Builds the first ``--episodes`` episodes of ``linear-fast`` at 224 px (or reuses
``--slice-dir``), then measures:

1. **Export** (``catalog export --format lerobot``, one process): frames/s against bare
   video encoding of the same frames (already decoded, same codec and settings, one
   process), and the round trip: every state, environment state and action of the
   export read back equal to the source, and the PSNR of every decoded video frame
   against the source's decoded JPEG (minimum and mean).
2. **Keyed loading**: random ``ds[i]`` over every frame with ``keys="lerobot"`` (float32
   and uint8 images) against the same pass with Dyana's own keys (best of
   ``--repeats``, shards already loaded).
3. With ``--lerobot-python PY`` (a Python with ``lerobot`` 0.3.2): the v2.1 export read
   item by item by ``LeRobotDataset`` (random order) against Dyana's keyed loader on the
   same frames, and one DataLoader epoch (2 workers, batch 32) each.

Times are wall-clock on an otherwise idle machine; the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_setup  # noqa: F401  (first: fixes sys.path)
import numpy as np

import catalog  # noqa: E402
from catalog.export.layout import VIDEO_KEY  # noqa: E402
from catalog.export.lerobot import ExportSettings  # noqa: E402
from catalog.export.video import VideoWriter, decode_frames, psnr  # noqa: E402
from pipeline.jobs.export import export  # noqa: E402

LEROBOT_TIMER = r'''
import json, sys, time
import numpy as np, torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
ds = LeRobotDataset("dyana/bench", root=sys.argv[1], video_backend="torchcodec")
order = np.random.default_rng(0).permutation(len(ds)).tolist()
ds[0]
start = time.perf_counter()
for i in order:
    ds[i]
random_fps = len(order) / (time.perf_counter() - start)
loader = torch.utils.data.DataLoader(ds, batch_size=32, shuffle=True, num_workers=2,
                                     generator=torch.Generator().manual_seed(0))
start = time.perf_counter()
for batch in loader:
    pass
epoch_s = time.perf_counter() - start
print(json.dumps({"random_fps": random_fps, "epoch_s": epoch_s, "frames": len(ds)}))
'''


def _random_pass(ds, order) -> float:
    for i in order[:64]:
        ds[i]
    start = time.perf_counter()
    for i in order:
        ds[i]
    return len(order) / (time.perf_counter() - start)


def _dyana_epoch(source: Path) -> float:
    import torch

    ds = catalog.open(source, keys="lerobot")
    loader = torch.utils.data.DataLoader(ds.torch(), batch_size=32, shuffle=True, num_workers=2,
                                         generator=torch.Generator().manual_seed(0))
    start = time.perf_counter()
    for _ in loader:
        pass
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--slice-dir", help="a built slice to use instead of building one")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--lerobot-python", help="a Python with lerobot 0.3.2 installed")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="dyana-bridge-") as tmp:
        work = Path(tmp)
        if args.slice_dir:
            source = Path(args.slice_dir)
        else:
            from pipeline.jobs.build import build

            build("linear-fast", work / "src", episodes=args.episodes, resolution=224, workers=2, progress=False)
            source = work / "src" / "linear-fast"
        with catalog.open(source) as ds:
            items = [ds[i] for i in range(len(ds))]
        frames = len(items)

        start = time.perf_counter()
        export(source, work / "v30", ExportSettings("lerobot"), workers=1)
        export_fps = frames / (time.perf_counter() - start)
        start = time.perf_counter()
        with VideoWriter(work / "bare.mp4", 224, 224, 20) as writer:
            for item in items:
                writer.add(item["image"])
        encode_fps = frames / (time.perf_counter() - start)

        import pyarrow.parquet as pq

        rows = []
        for path in sorted((work / "v30" / "data").rglob("*.parquet")):
            rows += pq.read_table(path).to_pylist()
        exact = all(
            np.array_equal(np.asarray(r["observation.state"], np.float32), np.concatenate([s["palm_pose"], s["joint_angles"]]))
            and np.array_equal(np.asarray(r["action"], np.float32), s["action"])
            and np.array_equal(np.asarray(r["observation.environment_state"], np.float32), s["object_pose"])
            for r, s in zip(rows, items)
        ) and len(rows) == frames
        decoded = [f for path in sorted((work / "v30" / "videos" / VIDEO_KEY).rglob("*.mp4"))
                   for _, f in decode_frames(path)]
        values = [psnr(a, s["image"]) for a, s in zip(decoded, items)]

        order = np.random.default_rng(0).permutation(frames).tolist()
        speeds: dict[str, float] = {"dyana": 0.0, "lerobot_float32": 0.0, "lerobot_uint8": 0.0}
        for _ in range(args.repeats):
            for name, options in (("dyana", {}), ("lerobot_float32", {"keys": "lerobot"}),
                                  ("lerobot_uint8", {"keys": "lerobot", "image_dtype": "uint8"})):
                with catalog.open(source, **options) as ds:
                    speeds[name] = max(speeds[name], _random_pass(ds, order))
        result = {
            "frames": frames,
            "export_fps": round(export_fps, 1),
            "bare_encode_fps": round(encode_fps, 1),
            "export_over_encode": round(export_fps / encode_fps, 3),
            "round_trip_exact": bool(exact),
            "video_frames": len(decoded),
            "psnr_min_db": round(min(values), 2),
            "psnr_mean_db": round(float(np.mean(values)), 2),
            "keyed_fps": {k: round(v, 1) for k, v in speeds.items()},
            "keyed_float32_ratio": round(speeds["lerobot_float32"] / speeds["dyana"], 3),
            "keyed_uint8_ratio": round(speeds["lerobot_uint8"] / speeds["dyana"], 3),
        }
        if args.lerobot_python:
            export(source, work / "v21", ExportSettings("lerobot-v2.1"), workers=2)
            out = subprocess.run([args.lerobot_python, "-c", LEROBOT_TIMER, str(work / "v21")],
                                 capture_output=True, text=True, check=True)
            theirs = json.loads(out.stdout.strip().splitlines()[-1])
            epoch = _dyana_epoch(source)
            result["lerobot_0_3_2"] = {
                "random_fps": round(theirs["random_fps"], 1),
                "epoch_s": round(theirs["epoch_s"], 2),
                "dyana_keyed_random_over_lerobot": round(speeds["lerobot_float32"] / theirs["random_fps"], 2),
                "dyana_epoch_s": round(epoch, 2),
                "dyana_epoch_speedup": round(theirs["epoch_s"] / epoch, 2),
            }
    print(f"{frames} frames of linear-fast at 224 px")
    print(f"  export {result['export_fps']} frames/s, bare encode {result['bare_encode_fps']} frames/s "
          f"(ratio {result['export_over_encode']}); round trip exact: {result['round_trip_exact']}; "
          f"PSNR min {result['psnr_min_db']} dB, mean {result['psnr_mean_db']} dB")
    print(f"  random ds[i]: {result['keyed_fps']} (keys=lerobot float32 {result['keyed_float32_ratio']}, "
          f"uint8 {result['keyed_uint8_ratio']} of Dyana's keys)")
    if "lerobot_0_3_2" in result:
        print(f"  LeRobot 0.3.2: {result['lerobot_0_3_2']}")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
