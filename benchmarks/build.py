"""Build throughput against pybullet's naive renderer, measured in one run.

- ``naive_render_fps``: TinyRenderer drawing the full scene (floor, table, object, hand)
  for every frame of the same episodes at the same resolution, in this process (one core).
- ``build_fps``: ``pipeline build`` end to end (episode stage, render, JPEG, Parquet +
  MCAP, manifest) with one worker, frames over wall time including cluster start-up.
- ``ratio`` = build_fps / naive_render_fps; ``workers_2_speedup`` = the 2-worker build's
  frames/s over the 1-worker build's.

Usage: python benchmarks/build.py [--slice circular-medium] [--episodes 96] [--json] [--quiet]
The last line printed is the JSON result; progress lines (per episode, at most one per
2 s) go to stderr unless --quiet.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from generators.recipe import slice_specs
from generators.render import Renderer
from pipeline.jobs.build import build
from pipeline.stages.episode import episode
from schemas.cli import ProgressMeter
from schemas.slices import get_slice


def _phase(title: str, quiet: bool) -> None:
    if not quiet:
        print(title, file=sys.stderr, flush=True)


def naive_render_fps(slice_name: str, episodes: int, resolution: int, quiet: bool = True) -> tuple[float, int]:
    specs = list(slice_specs(slice_name, episodes))
    _phase(f"episode stage, {len(specs)} episodes:", quiet)
    meter = None if quiet else ProgressMeter(len(specs))
    all_frames, planned = [], 0
    for spec in specs:
        all_frames.append((spec, episode(spec)))
        planned += all_frames[-1][1].num_frames
        if meter is not None:
            meter.update(len(all_frames), planned)
    _phase("naive TinyRenderer (timed):", quiet)
    meter = None if quiet else ProgressMeter(len(specs))
    count = 0
    with Renderer(resolution) as renderer:
        start = time.perf_counter()
        for k, (spec, frames) in enumerate(all_frames):
            renderer.render_episode(frames, spec.object, spec.object_size, spec.hand, full=True,
                                    obstacles=spec.obstacles)
            count += frames.num_frames
            if meter is not None:
                meter.update(k + 1, count)
        elapsed = time.perf_counter() - start
    return count / elapsed, count


def build_fps(slice_name: str, episodes: int, resolution: int, workers: int, shard_size: int,
              quiet: bool = True) -> tuple[float, str]:
    out = Path(tempfile.mkdtemp(prefix="dyana-bench-build-"))
    _phase(f"pipeline build, {workers} worker{'s' if workers > 1 else ''} (timed):", quiet)
    try:
        start = time.perf_counter()
        manifest = build(slice_name, out, episodes=episodes, workers=workers, resolution=resolution,
                         shard_size=shard_size, progress=not quiet)
        elapsed = time.perf_counter() - start
        return manifest.frames / elapsed, manifest.hash
    finally:
        shutil.rmtree(out, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slice", default="circular-medium")
    parser.add_argument("--episodes", type=int, default=96)
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--shard-size", type=int, default=12)
    parser.add_argument("--json", action="store_true", help="print only the JSON line")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    args = parser.parse_args(argv)
    get_slice(args.slice)

    naive, frames = naive_render_fps(args.slice, args.episodes, args.resolution, args.quiet)
    one, hash_one = build_fps(args.slice, args.episodes, args.resolution, 1, args.shard_size, args.quiet)
    two, hash_two = build_fps(args.slice, args.episodes, args.resolution, 2, args.shard_size, args.quiet)
    if hash_one != hash_two:
        print(f"catalog hashes differ between 1 and 2 workers: {hash_one} vs {hash_two}", file=sys.stderr)
        return 1
    result = {
        "naive_render_fps": round(naive, 1),
        "build_fps": round(one, 1),
        "ratio": round(one / naive, 3),
        "workers_2_speedup": round(two / one, 3),
        "build_fps_2_workers": round(two, 1),
        "frames": frames,
        "episodes": args.episodes,
        "resolution": args.resolution,
        "slice": args.slice,
    }
    if not args.json:
        print(f"naive TinyRenderer: {naive:.1f} frames/s; build 1 worker: {one:.1f} frames/s "
              f"(x{one / naive:.2f}); 2 workers: {two:.1f} frames/s (x{two / one:.2f} over 1)")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
