"""Build throughput: against pybullet's naive renderer, per stage, and against JPEG encoding alone.

- ``naive_render_fps``: TinyRenderer drawing the full scene (floor, table, object, hand)
  for every frame of the same episodes at the same resolution, in this process (one core).
- ``build_fps``: ``pipeline build`` end to end (episode stage, render, JPEG, Parquet +
  MCAP, manifest) with one worker, frames over wall time including cluster start-up.
- ``ratio`` = build_fps / naive_render_fps (wall, cluster start-up included);
  ``ratio_per_cpu_s`` = the profiled build's frames per CPU second / naive_render_fps
  (issue 38's measure, robust to other load); ``workers_2_speedup`` = the 2-worker build's
  frames/s over the 1-worker build's.
- ``profile_ms_per_frame``: one more real build of the same episodes, in this process
  (``workers=0``: the same shard task a worker runs, then the driver's statistics and
  manifest), with each stage's functions wrapped by a timer; a stage's time is this
  thread's CPU time inside its functions minus the stages nested in them, per frame.
  The stages: the episode stage, scene setup (loading an episode's bodies), posing (placing
  them for a frame), the draw (TinyRenderer's pass), the composite, JPEG encoding, Parquet,
  MCAP, hashing, statistics and the manifest; ``other`` is the rest of the build's CPU
  time (spec sampling, Python glue). An untimed warm-up build of ``--warmup`` episodes
  runs first, so what a process pays once (lazy imports, the renderer's plate) stays out
  of the per-frame figures (``warmup_cpu_s``). ``non_draw_share`` = every stage but the
  draw over the total, against ``non_draw_target``.
- ``jpeg_only_fps``: the same frames, decoded from that build's Parquet, encoded again with
  the build's encoder and options (OpenCV's ``imencode`` on the BGR pixels it decodes to),
  CPU time of the encode calls alone: the most frames/s a build that only encoded JPEG
  could reach on one core. ``build_fraction_of_jpeg`` = build_fps / jpeg_only_fps (wall
  time, the 1-worker build: frames/s per core); ``profile_fraction_of_jpeg`` = the profiled
  build's frames per CPU second / jpeg_only_fps (CPU time, robust to other load).

Usage: python benchmarks/build.py [--slice circular-medium] [--episodes 96] [--json] [--quiet]
           [--profile-only] [--warmup 1] [--results benchmarks/results/build_profile.json]
Prints the profile table, then the JSON result as the last line; progress lines (per
episode, at most one per 2 s) go to stderr unless --quiet. Run it under the shared lock
(``flock /tmp/dyana-bench.lock python benchmarks/build.py``).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)
import cv2
import numpy as np
import pyarrow.parquet as pq

import generators.encode as encode
import pipeline.stages.record as record
from generators.recipe import slice_specs
from generators.render import Renderer
from pipeline.jobs.build import build
from pipeline.stages.episode import episode
from schemas.cli import ProgressMeter
from schemas.slices import get_slice


@dataclass(frozen=True)
class Hook:
    """A function timed as part of ``stage``: attribute ``name`` of ``owner`` ("module" or
    "module:Class")."""

    stage: str
    owner: str
    name: str


#: The stages of a build, in the order they are printed, and the functions that make them up.
STAGES = ("episode stage", "scene setup", "posing", "window bounds", "draw", "composite", "JPEG encode", "Parquet", "MCAP",
          "hashing", "statistics", "manifest")
#: The stage the non-draw share leaves out: TinyRenderer's ``getCameraImage`` pass.
DRAW = "draw"
#: The largest share of a frame's CPU time all stages but the draw may take together (issue 30).
NON_DRAW_TARGET = 0.15
HOOKS = (
    Hook("episode stage", "pipeline.stages.episode", "episode"),
    Hook("episode stage", "pipeline.stages.record", "episode"),  # the name the shard task calls
    Hook("scene setup", "generators.render:Renderer", "set_scene"),
    Hook("posing", "generators.render:Renderer", "_pose"),
    Hook("window bounds", "generators.render:Renderer", "window"),  # the window renderer's bounds
    Hook("draw", "generators.render:Renderer", "_draw"),
    Hook("composite", "generators.render:Renderer", "render"),
    Hook("composite", "generators.render:Renderer", "render_bgr"),
    Hook("JPEG encode", "pipeline.stages.record", "encode_jpeg"),
    Hook("JPEG encode", "pipeline.stages.record", "encode_bgr_jpeg"),
    Hook("Parquet", "catalog.tables.shard", "frames_table"),
    Hook("Parquet", "catalog.tables.shard", "episode_row"),
    Hook("Parquet", "catalog.tables.shard", "episodes_table"),
    Hook("Parquet", "catalog.tables.shard", "write_table"),
    Hook("Parquet", "catalog.tables.parquet_io:TableWriter", "__init__"),
    Hook("Parquet", "catalog.tables.parquet_io:TableWriter", "write"),
    Hook("Parquet", "catalog.tables.parquet_io:TableWriter", "close"),
    Hook("MCAP", "catalog.tables.mcap_writer:McapShardWriter", "__init__"),
    Hook("MCAP", "catalog.tables.mcap_writer:McapShardWriter", "check_episode"),
    Hook("MCAP", "catalog.tables.mcap_writer:McapShardWriter", "add_episode"),
    Hook("MCAP", "catalog.tables.mcap_writer:McapShardWriter", "close"),
    Hook("hashing", "catalog.tables.shard", "sha256_file"),
    Hook("hashing", "catalog.tables.stats", "sha256_file"),
    Hook("statistics", "pipeline.jobs.build", "written_partial"),  # in the shard task since issue 37
    Hook("statistics", "pipeline.jobs.runner", "merge_partials"),
    Hook("statistics", "pipeline.jobs.runner", "shard_partial"),  # a shard without partial statistics
    Hook("statistics", "pipeline.jobs.runner", "write_stats"),
    Hook("manifest", "pipeline.jobs.runner", "write_manifest"),
    Hook("manifest", "catalog.store.manifest:Manifest", "create"),
)


def close_renderers() -> None:
    """Close this process's renderers (under their older private name in earlier checkouts)."""
    close = getattr(record, "close_renderers", None) or record._close_renderers  # type: ignore[attr-defined]
    close()


def _phase(title: str, quiet: bool) -> None:
    if not quiet:
        print(title, file=sys.stderr, flush=True)


def _owner(path: str):
    module, _, cls = path.partition(":")
    target = importlib.import_module(module)
    return getattr(target, cls) if cls else target


class StageClock:
    """Exclusive CPU time per stage: time inside a hooked function, minus the hooked
    functions it calls (which count for their own stage)."""

    def __init__(self, stages: tuple[str, ...] = STAGES) -> None:
        self.totals = dict.fromkeys(stages, 0.0)
        self._nested: list[float] = []

    def wrap(self, stage: str, fn):
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            self._nested.append(0.0)
            start = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = time.thread_time() - start
                inner = self._nested.pop()
                self.totals[stage] += elapsed - inner
                if self._nested:
                    self._nested[-1] += elapsed

        return timed


@contextlib.contextmanager
def hooked(clock: StageClock, hooks: tuple[Hook, ...] = HOOKS) -> Iterator[list[str]]:
    """Wrap every hook's function with ``clock`` for the duration; yields the stages none of
    whose functions exist. (A stage lists the names of older code too, so the same script
    profiles an earlier checkout.)"""
    saved, found = [], set()
    try:
        for hook in hooks:
            owner = _owner(hook.owner)
            fn = owner.__dict__.get(hook.name) if isinstance(owner, type) else getattr(owner, hook.name, None)
            if fn is None:
                continue
            found.add(hook.stage)
            saved.append((owner, hook.name, fn))
            wrapped = (classmethod(clock.wrap(hook.stage, fn.__func__)) if isinstance(fn, classmethod)
                       else clock.wrap(hook.stage, fn))
            setattr(owner, hook.name, wrapped)
        yield [stage for stage in clock.totals if stage not in found]
    finally:
        for owner, name, fn in reversed(saved):
            setattr(owner, name, fn)


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


@dataclass(frozen=True)
class Profile:
    """One profiled in-process build: CPU ms per frame by stage, totals and its hash."""

    frames: int
    ms_per_frame: dict[str, float]
    cpu_s: float
    wall_s: float
    hash: str
    missing: tuple[str, ...]  # stages without a hooked function
    jpeg_only_fps: float
    warmup_cpu_s: float  # the untimed warm-up build before it (imports, renderer set-up, its episodes)

    @property
    def non_draw_share(self) -> float:
        """Every stage but the draw, together, over the frame's CPU time."""
        total = sum(self.ms_per_frame.values())
        return (total - self.ms_per_frame[DRAW]) / total


def profile_build(slice_name: str, episodes: int, resolution: int, shard_size: int, quiet: bool = True,
                  warmup: int = 1) -> Profile:
    """Build in this process with every stage timed, then time JPEG encoding alone on the
    frames it wrote. A warm-up build of the slice's first ``warmup`` episodes runs first,
    untimed (its CPU time is kept apart): what a worker pays once (lazy imports such as
    pyarrow's of pandas, the renderer's plate) then stays out of the per-frame figures.
    The renderers it made are closed, so the timed build starts from fresh ones."""
    clock = StageClock()
    out = Path(tempfile.mkdtemp(prefix="dyana-bench-profile-"))
    try:
        warm = time.thread_time()
        if warmup:
            _phase(f"warm-up build of {warmup} episode(s), untimed:", quiet)
            build(slice_name, out / "warmup", episodes=warmup, workers=0, resolution=resolution,
                  shard_size=shard_size, progress=False)
            close_renderers()
        warm = time.thread_time() - warm
        _phase("pipeline build in this process, stages timed:", quiet)
        with hooked(clock) as missing:
            wall, cpu = time.perf_counter(), time.thread_time()
            manifest = build(slice_name, out / "timed", episodes=episodes, workers=0, resolution=resolution,
                             shard_size=shard_size, progress=not quiet)
            cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
        frames = manifest.frames
        ms = {stage: 1000.0 * clock.totals[stage] / frames for stage in STAGES}
        ms["other"] = 1000.0 * (cpu - sum(clock.totals.values())) / frames
        _phase("JPEG encoding alone, the same frames (timed):", quiet)
        jpeg = jpeg_only_fps(out / "timed" / slice_name / "frames")
        return Profile(frames, ms, cpu, wall, manifest.hash, tuple(missing), jpeg, warm)
    finally:
        shutil.rmtree(out, ignore_errors=True)


def _jpeg_params(quality: int) -> list[int]:
    """The build's ``cv2.imencode`` options (under their older private name in earlier checkouts)."""
    params = getattr(encode, "jpeg_params", None) or encode._params  # type: ignore[attr-defined]
    return params(quality)


def decode_bgr(data: bytes) -> np.ndarray:
    bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"an image of {len(data)} bytes does not decode")
    return bgr


def jpeg_only_fps(frames_dir: Path) -> float:
    """Frames per CPU second of ``cv2.imencode`` with the build's options over every frame
    stored in ``frames_dir`` (decoded one row group at a time; only the encoding is timed)."""
    params = _jpeg_params(encode.JPEG_QUALITY)
    count, elapsed = 0, 0.0
    for path in sorted(frames_dir.glob("*.parquet")):
        parquet = pq.ParquetFile(path)
        for group in range(parquet.num_row_groups):
            images = parquet.read_row_group(group, columns=["image"]).column("image").to_pylist()
            decoded = [decode_bgr(data) for data in images]
            start = time.thread_time()
            for bgr in decoded:
                cv2.imencode(".jpg", bgr, params)
            elapsed += time.thread_time() - start
            count += len(decoded)
    return count / elapsed


def profile_table(profile: Profile) -> str:
    total = sum(profile.ms_per_frame.values())
    lines = [f"per-stage profile: {profile.frames} frames, one core, CPU ms per frame",
             f"{'stage':<14} {'ms/frame':>9} {'share':>7}"]
    for stage, ms in profile.ms_per_frame.items():
        lines.append(f"{stage:<14} {ms:9.3f} {100.0 * ms / total:6.1f}%")
    lines.append(f"{'total':<14} {total:9.3f} {100.0:6.1f}%  ({1000.0 / total:.1f} frames per CPU second)")
    lines.append(f"{'JPEG alone':<14} {1000.0 / profile.jpeg_only_fps:9.3f}          "
                 f"({profile.jpeg_only_fps:.1f} frames per CPU second)")
    lines.append(f"non-draw share = {100.0 * profile.non_draw_share:.1f}% (target <= {100.0 * NON_DRAW_TARGET:.0f}%): "
                 f"every stage but the draw, {total - profile.ms_per_frame[DRAW]:.3f} of {total:.3f} ms per frame")
    lines.append(f"warm-up build before it (untimed stages, once per process): {profile.warmup_cpu_s:.2f} CPU s")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slice", default="circular-medium")
    parser.add_argument("--episodes", type=int, default=96)
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--shard-size", type=int, default=12)
    parser.add_argument("--json", action="store_true", help="print only the JSON line")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    parser.add_argument("--profile-only", action="store_true",
                        help="only the profiled in-process build and JPEG alone (no naive render, no Dask builds)")
    parser.add_argument("--warmup", type=int, default=1,
                        help="episodes of the untimed warm-up build before the profiled one (0: none)")
    parser.add_argument("--results", type=Path, default=None,
                        help="also write the JSON result to this file (e.g. benchmarks/results/build_profile.json)")
    args = parser.parse_args(argv)
    get_slice(args.slice)

    result: dict = {"load_average_start": [round(v, 2) for v in os.getloadavg()]}
    profile = profile_build(args.slice, args.episodes, args.resolution, args.shard_size, args.quiet, args.warmup)
    per_cpu_s = profile.frames / profile.cpu_s
    if not args.profile_only:
        naive, frames = naive_render_fps(args.slice, args.episodes, args.resolution, args.quiet)
        one, hash_one = build_fps(args.slice, args.episodes, args.resolution, 1, args.shard_size, args.quiet)
        two, hash_two = build_fps(args.slice, args.episodes, args.resolution, 2, args.shard_size, args.quiet)
        if len({hash_one, hash_two, profile.hash}) != 1:
            print(f"catalog hashes differ: 1 worker {hash_one}, 2 workers {hash_two}, in process {profile.hash}",
                  file=sys.stderr)
            return 1
        result |= {
            "naive_render_fps": round(naive, 1),
            "build_fps": round(one, 1),
            "ratio": round(one / naive, 3),
            # issue 38's measure: the build's frames per CPU second (the profiled build) over the
            # naive render's (in process, one core: its wall time is its CPU time)
            "ratio_per_cpu_s": round(per_cpu_s / naive, 3),
            "workers_2_speedup": round(two / one, 3),
            "build_fps_2_workers": round(two, 1),
            "build_fraction_of_jpeg": round(one / profile.jpeg_only_fps, 3),
        }
    result.update({
        "profile_ms_per_frame": {stage: round(ms, 3) for stage, ms in profile.ms_per_frame.items()},
        "profile_fps_per_cpu_s": round(per_cpu_s, 1),
        "non_draw_share": round(profile.non_draw_share, 4),
        "non_draw_target": NON_DRAW_TARGET,
        "warmup_episodes": args.warmup,
        "warmup_cpu_s": round(profile.warmup_cpu_s, 3),
        "jpeg_only_fps": round(profile.jpeg_only_fps, 1),
        "profile_fraction_of_jpeg": round(per_cpu_s / profile.jpeg_only_fps, 3),
        "hash": profile.hash[:16],
        "frames": profile.frames,
        "episodes": args.episodes,
        "resolution": args.resolution,
        "slice": args.slice,
        "load_average_end": [round(v, 2) for v in os.getloadavg()],
        **{k: v for k, v in bench_setup.provenance().items() if k != "load_average"},
    })
    if profile.missing:
        print(f"stages not found (not timed): {', '.join(profile.missing)}", file=sys.stderr, flush=True)
    if not args.json:
        print(profile_table(profile))
        if not args.profile_only:
            print(f"naive TinyRenderer: {naive:.1f} frames/s; build 1 worker: {one:.1f} frames/s "
                  f"(x{one / naive:.2f}; {one / profile.jpeg_only_fps:.3f} of JPEG alone); "
                  f"2 workers: {two:.1f} frames/s (x{two / one:.2f} over 1)")
    print(json.dumps(result))
    if args.results is not None:
        args.results.write_text(json.dumps(result) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
