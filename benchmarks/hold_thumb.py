"""An experiment, not the dataset's hand: does an opposable thumb make the ground truth hold?

``benchmarks/hold.py`` finds that the ground truth's grasp does not hold: palm down, the
fingers reach the object's front (+Z) from above and the thumb (root at the palm's side,
pointing out and forward) reaches its side; nothing pushes from behind, so squeezing pushes
the object out and lifting leaves it. This script moves the thumb (in this process only,
by setting :mod:`generators.hand`'s module state) to :data:`THUMB_ROOT`, pointing back
along :data:`THUMB_ALONG` and flexing down and forward (:data:`THUMB_CURL`), so that it
closes on the object's back, opposite the fingers, and measures with the same hold test:

- ``at_rest``: each object at rest at 0.85 and 1.15 of its nominal size, palm at the
  ground truth's hover point (``hover``) and resting on the object (``resting``: 0.23
  lower, the palm's underside on its top), fingers closed until they touch it;
- ``ground_truth``: the ground truth of the slice's first N episodes planned with this
  hand, the dataset's specs, with the palm hover ``--hover`` (the dataset's 0.35, or 0.12
  to rest the palm on the object), by object; an episode the planner refuses with this hand
  and hover (e.g. fingertips through the table) is counted as infeasible, not tested.

    python benchmarks/hold_thumb.py [--episodes 200] [--out benchmarks/results/hold_thumb.json]

It runs each hover in its own process (the grasp caches are per process) and writes one
JSON file with the commit, dataset version and load averages.
"""

from __future__ import annotations

import argparse
import collections
import datetime
import json
import os
import subprocess
import sys
from pathlib import Path

import bench_setup
import numpy as np

RESULT = Path(bench_setup.HERE) / "results" / "hold_thumb.json"
THUMB_ROOT = (-0.1, -0.1, -0.5)
THUMB_ALONG = (0.0, -0.45, -0.9)
THUMB_CURL = (0.0, -0.9, 0.45)
HOVERS = (0.35, 0.12)


def patch_thumb(hover: float) -> None:
    """Move the right hand's thumb (the left mirrors it) and set the palm's hover height."""
    import generators.grasp
    import generators.hand as hand
    import generators.interception

    along = np.array(THUMB_ALONG) / np.linalg.norm(THUMB_ALONG)
    curl = np.array(THUMB_CURL) - np.dot(THUMB_CURL, along) * along
    curl /= np.linalg.norm(curl)
    axis = np.cross(along, curl)
    rotation = np.stack([axis, np.cross(along, axis), along], axis=1)
    roots = hand.root_positions("right")
    roots[0] = THUMB_ROOT
    hand._ROOTS_RIGHT = roots
    hand._thumb_root_right = lambda: rotation.copy()
    hand._CACHE = {side: (hand.root_positions(side), hand.root_rotations(side)) for side in hand.SIDES}
    generators.grasp.PALM_HOVER = hover
    generators.interception.PALM_HOVER = hover


def one(hover: float, episodes: int) -> dict:
    patch_thumb(hover)
    from generators.ground_truth import plan
    from generators.hold import hold_test
    from generators.hold_episode import episode_hold
    from generators.hold_grasp import closing_angles, hover_palm, resting_pose
    from generators.recipe import spec_for
    from schemas.errors import InfeasibleError
    from schemas.objects import OBJECTS

    at_rest = {}
    for name, cat in OBJECTS.items():
        row = {}
        for label, dy in (("hover", 0.0), ("resting", -0.23)):
            held = 0
            for factor in (0.85, 1.15):
                size = cat.nominal_size * factor
                palm = hover_palm(name, size, (0.0, dy, 0.0))
                joints = closing_angles(name, size, "right", palm)
                still = np.zeros(3)
                held += hold_test(name, size, "right", palm, still, joints, resting_pose(name, size), still, still).held
            row[label] = held
        at_rest[name] = row
    groups: dict[str, list[bool]] = collections.defaultdict(list)
    infeasible: collections.Counter[str] = collections.Counter()
    for i in range(episodes):
        spec = spec_for("test-1k", i)
        try:
            hp = plan(spec)[0]
        except InfeasibleError:
            infeasible[spec.object] += 1
            continue
        out = episode_hold(spec, hp.palm_pose, hp.joint_angles)
        groups[spec.object].append(bool(out is not None and out[1].held))
    everything = [h for v in groups.values() for h in v]
    return {"hover": hover, "at_rest_held_of_2": at_rest,
            "ground_truth": {"n": len(everything), "held": sum(everything),
                             "rate": round(sum(everything) / max(len(everything), 1), 4),
                             "by_object": {k: {"n": len(v), "held": sum(v)} for k, v in sorted(groups.items())},
                             "infeasible_by_object": dict(sorted(infeasible.items()))}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--hover", type=float, help="run one hover in this process and print its JSON")
    parser.add_argument("--out", type=Path, default=RESULT)
    args = parser.parse_args(argv)
    if args.hover is not None:
        print(json.dumps(one(args.hover, args.episodes)))
        return 0
    load_start = os.getloadavg()
    started = datetime.datetime.now(datetime.UTC)
    runs = []
    for hover in HOVERS:
        done = subprocess.run([sys.executable, __file__, "--hover", str(hover), "--episodes", str(args.episodes)],
                              check=True, capture_output=True, text=True)
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    from catalog.store.manifest import git_commit
    from schemas.versions import DATASET_VERSION

    record = {"date_utc": started.strftime("%Y-%m-%d %H:%M"), "commit": git_commit(bench_setup.ROOT),
              "dataset_version": DATASET_VERSION, "cores": os.cpu_count(),
              "load_average_start": [round(x, 2) for x in load_start],
              "thumb": {"root": THUMB_ROOT, "along": THUMB_ALONG, "curl": THUMB_CURL}, "episodes": args.episodes,
              "runs": runs, "load_average_end": [round(x, 2) for x in os.getloadavg()]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
    print(json.dumps(runs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
