"""How much of its object every episode shows: segmentation masks over a sample of the recipe.

Samples ``--per-source`` episodes (seeded) from each of the nine atomic slices and
``test-1k``, plays their ground truth and renders TinyRenderer segmentation masks of
the moving bodies (:meth:`generators.render.Renderer.object_pixels`): for each frame,
the object's pixels with the hand where it is, and with the hand moved out of view.

* Observe frames: the *visible fraction* (shown / alone pixels), its minimum, 1st
  percentile and median; the recipe promises at least 0.5 (``MIN_OBSERVE_VISIBLE``).
* Acting frames before the hand arrives: the share with the whole object inside the
  image (every surface point in the view frustum), and the share with at least half
  of it unhidden by the moving hand.
* The analytic test (:mod:`generators.visibility`) against the masks on the observe
  frames: the largest amount by which it calls an object more visible than the mask.

Prints one table row per source and overall, then, as the last line, one JSON object.
Runs ``--workers`` processes (default 2). Tiny check: ``--per-source 2 --workers 1``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import time

import bench_setup  # noqa: F401  (puts the repository first on sys.path)
import numpy as np

from generators.camera import points_in_view  # noqa: E402
from generators.recipe import spec_for  # noqa: E402
from generators.render import Renderer  # noqa: E402
from generators.visibility import object_surface_points, observe_visibility  # noqa: E402
from pipeline import episode  # noqa: E402
from schemas.scene import MIN_OBSERVE_VISIBLE  # noqa: E402
from schemas.slices import ATOMIC_SLICES, SLICES  # noqa: E402

SOURCES = ATOMIC_SLICES + ("test-1k",)


def sample(per_source: int, seed: int) -> list[tuple[str, int]]:
    """``per_source`` distinct episode indices of each source, from a seeded generator."""
    out = []
    for k, name in enumerate(SOURCES):
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, k])))
        order = np.argsort(rng.random(SLICES[name].episodes), kind="stable")
        out.extend((name, int(i)) for i in np.sort(order[:per_source]))
    return out


def measure(job: tuple[str, int, int]) -> dict:
    """Masks of one episode's observe frames and acting frames before arrival."""
    name, index, resolution = job
    spec = spec_for(name, index)
    frames = episode(spec)
    a, i = spec.observe_frames, spec.intercept_frame
    observe, acting_in_view, acting_unhidden = [], [], []
    with Renderer(resolution) as renderer:
        renderer.set_scene(spec.object, spec.object_size, spec.hand, spec.obstacles)
        for k in range(i):
            shown, alone = renderer.object_pixels(frames.object_pose[k], frames.palm_pose[k], frames.joint_angles[k])
            fraction = shown / alone if alone else 0.0
            if k < a:
                observe.append(fraction)
            else:
                points = object_surface_points(spec.object, spec.object_size, frames.object_pose[k].astype(np.float64))
                acting_in_view.append(bool(points_in_view(points).all()))
                acting_unhidden.append(fraction >= MIN_OBSERVE_VISIBLE)
    analytic = observe_visibility(spec.object, spec.object_size, spec.hand, frames.object_pose[:a].astype(np.float64),
                                  obstacles=spec.obstacles)
    return {
        "source": name,
        "episode": index,
        "observe": observe,
        "analytic_excess": float(np.max(analytic - np.asarray(observe))) if a else None,
        "acting_in_view": acting_in_view,
        "acting_unhidden": acting_unhidden,
    }


def summarize(rows: list[dict]) -> dict:
    observe = np.array([f for r in rows for f in r["observe"]])
    in_view = np.array([f for r in rows for f in r["acting_in_view"]], dtype=bool)
    unhidden = np.array([f for r in rows for f in r["acting_unhidden"]], dtype=bool)
    excess = [r["analytic_excess"] for r in rows if r["analytic_excess"] is not None]
    return {
        "episodes": len(rows),
        "observed_episodes": sum(1 for r in rows if r["observe"]),
        "observe_frames": int(observe.size),
        "observe_visible_min": round(float(observe.min()), 4) if observe.size else None,
        "observe_visible_p1": round(float(np.percentile(observe, 1)), 4) if observe.size else None,
        "observe_visible_median": round(float(np.median(observe)), 4) if observe.size else None,
        "acting_frames_before_arrival": int(in_view.size),
        "acting_in_view_share": round(float(in_view.mean()), 4) if in_view.size else None,
        "acting_half_unhidden_share": round(float(unhidden.mean()), 4) if unhidden.size else None,
        "analytic_max_excess": round(max(excess), 4) if excess else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-source", type=int, default=200, help="episodes sampled from each source")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    jobs = [(name, index, args.resolution) for name, index in sample(args.per_source, args.seed)]
    load_start = [round(v, 2) for v in os.getloadavg()]
    print(f"{len(jobs)} episodes ({args.per_source} from each of {len(SOURCES)} sources) on {args.workers} workers",
          flush=True)
    start = time.perf_counter()
    rows: list[dict] = []
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        for row in pool.imap(measure, jobs, chunksize=4):
            rows.append(row)
            if len(rows) % 100 == 0:
                print(f"[{len(rows)}/{len(jobs)} episodes, {time.perf_counter() - start:.0f} s]", flush=True)
    result = {name: summarize([r for r in rows if r["source"] == name]) for name in SOURCES}
    result["all"] = summarize(rows)
    header = ("source", "episodes", "observe frames", "min", "p1", "median", "acting frames", "in view", ">=50% unhidden")
    print(" | ".join(header))
    for name, s in result.items():
        print(
            f"{name} | {s['episodes']} | {s['observe_frames']} | {s['observe_visible_min']} | "
            f"{s['observe_visible_p1']} | {s['observe_visible_median']} | {s['acting_frames_before_arrival']} | "
            f"{s['acting_in_view_share']} | {s['acting_half_unhidden_share']}"
        )
    result["resolution"] = args.resolution
    result["seconds"] = round(time.perf_counter() - start, 1)
    result.update({k: v for k, v in bench_setup.provenance().items() if k != "load_average"})
    result["load_average_start"], result["load_average_end"] = load_start, [round(v, 2) for v in os.getloadavg()]
    print(json.dumps(result, sort_keys=True))


if __name__ == "__main__":
    main()
