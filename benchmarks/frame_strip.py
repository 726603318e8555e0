"""A frame strip of one episode, readable at a paper's column width: six frames of its
ground truth (the start, the middle and end of the observe window, halfway to arrival,
arrival, the last frame), each labelled with its frame index and phase, and the
object's path so far drawn over it; for a flying object also its ground track (the path
dropped onto the table, dotted grey), so its height reads as the gap between the two.
Beside the PNG, ``<out>.json`` records the episode, the frames drawn, the commit, the
dataset version and the load (the results pages quote it).

    python benchmarks/frame_strip.py --slice irregular-medium --episode 4 --out benchmarks/results/irregular_strip.png
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import bench_setup  # noqa: F401  (first: fixes sys.path)
import numpy as np

from generators.camera import project  # noqa: E402
from generators.recipe import spec_for  # noqa: E402
from generators.render import Renderer  # noqa: E402
from pipeline import episode  # noqa: E402
from schemas.scene import PHASES  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slice", required=True)
    parser.add_argument("--episode", type=int, default=0)
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    spec = spec_for(args.slice, args.episode)
    frames = episode(spec)
    a, i, n = spec.observe_frames, spec.intercept_frame, spec.num_frames
    picks = sorted({0, a // 2, max(a - 1, 0), a + (i - a) // 2, i, n - 1})
    with Renderer(args.resolution) as renderer:
        renderer.set_scene(spec.object, spec.object_size, spec.hand, spec.obstacles)
        images = [renderer.render(frames.object_pose[k], frames.palm_pose[k], frames.joint_angles[k]) for k in picks]
    path, _ = project(frames.object_pose[:, :3].astype(np.float64), args.resolution, args.resolution)
    ground = frames.object_pose[:, :3].astype(np.float64)
    ground[:, 1] = 0.0
    track, _ = project(ground, args.resolution, args.resolution)
    figure, axes = plt.subplots(1, len(picks), figsize=(7.0, 7.0 / len(picks) + 0.55), dpi=200)
    for ax, k, image in zip(axes, picks, images):
        ax.imshow(image)
        if spec.motion.airborne:
            ax.plot(track[: k + 1, 0], track[: k + 1, 1], color="0.35", linewidth=0.6, linestyle=":")
        ax.plot(path[: k + 1, 0], path[: k + 1, 1], color="#D55E00", linewidth=0.8)
        ax.plot(path[a:, 0][: max(k + 1 - a, 0)], path[a:, 1][: max(k + 1 - a, 0)], color="#0072B2", linewidth=0.8)
        ax.set_title(f"frame {k}\n{PHASES[frames.phase[k]]}", fontsize=6.5, pad=2)
        ax.axis("off")
    figure.suptitle(f"{spec.episode_id}: {spec.text} (orange: observed path, blue: after the first acting frame)",
                    fontsize=6.5, y=0.99)
    figure.subplots_adjust(left=0.01, right=0.99, top=0.8, bottom=0.01, wspace=0.04)
    figure.savefig(args.out, metadata={"Software": None})
    record = {"benchmark": "frame_strip", "slice": args.slice, "episode": args.episode, "episode_id": spec.episode_id,
              "resolution": args.resolution, "frames": picks, **bench_setup.provenance()}
    with open(os.path.splitext(args.out)[0] + ".json", "w") as handle:
        handle.write(json.dumps(record, indent=1) + "\n")
    print(f"{args.out}: frames {picks} of {spec.episode_id}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
