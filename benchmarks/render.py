"""Frames per second of the composited renderer against the naive full-scene render.

Both draw the same episode-like pose sequences (an object rolling or sliding across
the workspace, the hand moving from rest to hover over it, the fingers closing) at
the same resolution, pinned to one core and timed in process CPU time (robust to other
load on a shared machine). The naive baseline is pybullet's TinyRenderer drawing the
whole scene each frame (``Renderer.render_full``). Every composited frame is checked
equal to its full render; JPEG encoding of the frames is timed alongside.

    python benchmarks/render.py [--resolution 224] [--episodes 8] [--frames 40]

Prints a summary, then one JSON line:
``{"naive_render_fps", "composited_fps", "ratio", ...}``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time

import numpy as np

from generators.encode import JPEG_QUALITY, encode_jpeg
from generators.hand import JOINT_LOWER, JOINT_UPPER, REST_JOINTS, REST_PALM
from generators.render import Renderer
from schemas.objects import OBJECTS
from schemas.scene import HANDS, PALM_HOVER, WORKSPACE_X, WORKSPACE_Z


def episodes(rng: np.random.Generator, count: int, frames: int):
    """Synthetic but realistic episodes: (object, size, hand, object poses, palm poses, joints)."""
    names = sorted(OBJECTS)
    for e in range(count):
        name = names[rng.integers(len(names))]
        cat = OBJECTS[name]
        size = cat.nominal_size * rng.uniform(0.8, 1.2)
        y = cat.half_height(size)
        start = np.array([rng.uniform(*WORKSPACE_X), rng.uniform(*WORKSPACE_Z)])
        end = np.array([rng.uniform(*WORKSPACE_X), rng.uniform(*WORKSPACE_Z)])
        s = np.linspace(0.0, 1.0, frames)[:, None]
        xz = start + (end - start) * s
        angle = rng.uniform(0, 2 * np.pi) + np.linspace(0, 6.0, frames) * cat.rolling
        quat = np.stack([np.sin(angle / 2), np.zeros(frames), np.zeros(frames), np.cos(angle / 2)], axis=1)
        obj = np.concatenate([xz[:, :1], np.full((frames, 1), y), xz[:, 1:], quat], axis=1)
        arrive = frames * 2 // 3
        w = np.clip(np.arange(frames) / arrive, 0.0, 1.0)[:, None]
        w = w * w * (3 - 2 * w)
        hover = np.concatenate([obj[:, :1], 2 * y + PALM_HOVER + np.zeros((frames, 1)), obj[:, 2:3]], axis=1)
        palm = np.concatenate([np.asarray(REST_PALM[:3]) * (1 - w) + hover * w, np.zeros((frames, 3))], axis=1)
        close = np.clip((np.arange(frames) - arrive) / 6.0, 0.0, 1.0)[:, None]
        grasp = rng.uniform(JOINT_LOWER, JOINT_UPPER) * 0.7
        joints = REST_JOINTS * (1 - close) + grasp * close
        yield name, size, HANDS[e % 2], obj, palm, joints


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--frames", type=int, default=40, help="frames per episode")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

    eps = list(episodes(np.random.default_rng(args.seed), args.episodes, args.frames))
    n = args.episodes * args.frames
    timings, digests = {}, {}
    with Renderer(args.resolution) as renderer:
        for mode, draw in (("naive", renderer.render_full), ("composited", renderer.render)):
            hashes = []
            elapsed = 0.0
            last = None
            for name, size, hand, obj, palm, joints in eps:
                renderer.set_scene(name, size, hand)
                for i in range(len(obj)):
                    t0 = time.process_time()
                    img = draw(obj[i], palm[i], joints[i])
                    elapsed += time.process_time() - t0
                    hashes.append(hashlib.sha256(img.tobytes()).digest())
                    last = img
            timings[mode], digests[mode] = elapsed, hashes
        fallbacks = renderer.fallbacks
    t0 = time.process_time()
    for _ in range(100):
        encode_jpeg(last, JPEG_QUALITY)
    encode_ms = (time.process_time() - t0) * 10.0
    equal = digests["naive"] == digests["composited"]
    naive, fast = n / timings["naive"], n / timings["composited"]
    print(f"{n} frames at {args.resolution} px on one core", file=sys.stderr)
    print(f"naive full-scene TinyRenderer: {naive:8.1f} frames/s", file=sys.stderr)
    print(f"composited over static plate:  {fast:8.1f} frames/s ({fallbacks} full-render fallbacks)", file=sys.stderr)
    print(f"composited frames equal full renders: {equal}", file=sys.stderr)
    print(f"JPEG encoding (quality {JPEG_QUALITY}): {encode_ms:.3f} ms/frame", file=sys.stderr)
    print(
        json.dumps(
            {
                "benchmark": "render",
                "naive_render_fps": round(naive, 2),
                "composited_fps": round(fast, 2),
                "ratio": round(fast / naive, 3),
                "resolution": args.resolution,
                "frames": n,
                "fallbacks": fallbacks,
                "identical": equal,
                "jpeg_encode_ms": round(encode_ms, 3),
            }
        )
    )
    return 0 if equal else 1


if __name__ == "__main__":
    sys.exit(main())
