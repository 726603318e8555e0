"""Disk footprint: bytes per frame of each stored table, measured per slice, for `catalog list`.

For every buildable slice, ``--sample`` episodes spread evenly over the slice (indices
round(i * n / k)) are built at 224 px through ``pipeline build --specs`` (the specs renumbered
0..k-1, everything else as the recipe has it); the frames and MCAP bytes are divided by the
sample's frames and the episodes table's bytes by its episodes. The result is written to
``catalog/store/footprint.json`` (read by ``catalog list`` and :mod:`catalog.store.footprint`), which this
script regenerates; the last line printed is JSON.

    python benchmarks/footprint.py                # 24 episodes per slice
    python benchmarks/footprint.py --sample 4     # a quick check (not written unless --write)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)

from catalog.store.footprint import FOOTPRINT_PATH
from catalog.store.manifest import load_manifest
from generators.recipe import spec_for
from pipeline.jobs.build import build
from schemas.slices import SLICES
from schemas.versions import DATASET_VERSION


def sample_specs(slice_name: str, sample: int) -> list:
    total = SLICES[slice_name].episodes
    count = min(sample, total)
    indices = sorted({round(i * total / count) for i in range(count)})
    return [dataclasses.replace(spec_for(slice_name, index), episode_index=k) for k, index in enumerate(indices)]


def measure(slice_name: str, sample: int, workers: int, scratch: Path) -> dict:
    specs = sample_specs(slice_name, sample)
    scratch.mkdir(parents=True, exist_ok=True)
    path = scratch / f"{slice_name}.jsonl"
    path.write_text("".join(s.to_json() + "\n" for s in specs))
    build(None, scratch / "out", specs_path=str(path), workers=workers, shard_size=len(specs), progress=False)
    manifest = load_manifest(scratch / "out" / slice_name)
    sizes = {kind: sum(s.files[kind].size for s in manifest.shards) for kind in ("frames", "episodes", "mcap")}
    return {
        "episodes": manifest.episodes,
        "frames": manifest.frames,
        "frames_bytes_per_frame": round(sizes["frames"] / manifest.frames, 1),
        "mcap_bytes_per_frame": round(sizes["mcap"] / manifest.frames, 1),
        "episodes_bytes_per_episode": round(sizes["episodes"] / manifest.episodes, 1),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sample", type=int, default=24, help="episodes per slice (default 24)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--write", action="store_true", help="write catalog/store/footprint.json (default with --sample 24+)")
    args = parser.parse_args(argv)
    names = [name for name, d in SLICES.items() if not d.union]
    rows = {}
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="dyana-footprint-") as tmp:
        for k, name in enumerate(names, 1):
            rows[name] = measure(name, args.sample, args.workers, Path(tmp) / name)
            row = rows[name]
            print(f"[{k}/{len(names)}] {name:<17} frames {row['frames_bytes_per_frame']:>8.0f} B/frame  "
                  f"mcap {row['mcap_bytes_per_frame']:>8.0f} B/frame  "
                  f"({row['episodes']} episodes, {row['frames']} frames, {time.perf_counter() - started:.0f} s)",
                  file=sys.stderr, flush=True)
    result = {"dataset_version": DATASET_VERSION, "resolution": 224, "sample_episodes": args.sample, "slices": rows}
    if args.write or args.sample >= 24:
        FOOTPRINT_PATH.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
        print(f"wrote {FOOTPRINT_PATH}", file=sys.stderr)
    print(json.dumps(result, sort_keys=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
