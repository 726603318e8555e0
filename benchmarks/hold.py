"""The hold test (:mod:`generators.hold`, issue 38's S_hold) on a slice: who holds, and what it costs.

For each of the first N episodes of the slice (default test-1k, all 1,000):

- ``ground_truth``: the ground-truth hand (:func:`generators.ground_truth.plan`), tested
  from its first closed frame (:func:`generators.hold_episode.episode_hold`); held rate
  overall, by object, motion type, interception setting, hand and the object's speed at
  that frame; slip, rise and contacts of every failure kind;
- ``oracle``: the same plan's states as the environment holds them (float32), what the
  oracle policy reaches through the current environment;
- ``controls`` at the ground truth's closed frame: ``open`` (the palm where it is, the
  fingers at rest: not closed) and ``beside`` (the closed hand 1 unit to the side);
- ``blind``: the four blind policies (:mod:`pipeline.policies.blind`) played in a
  kinematic stand-in of the environment (the hand is set to each clipped float32 action,
  as :class:`pipeline.loop.env.DyanaEnv` does, no images), ``blind-first-seen`` given the
  object's true first position (the best its locator can do), on the first
  ``--blind-episodes`` episodes;
- ``placements``: for each object at rest at its nominal size, which palm offsets from
  the ground truth's hover point (a grid, :data:`OFFSETS_X` ...) hold it, the fingers
  closed until they touch it (:func:`generators.hold_grasp.closing_angles`);
- ``cost``: CPU seconds of one hold test (mean, p95, max) and per frame of an average
  ground-truth episode (one test per episode over its frames);
- ``determinism``: the first 20 ground-truth tests run again give the same floats.

    python benchmarks/hold.py [--slice test-1k] [--episodes 1000] [--blind-episodes 200]
                              [--out benchmarks/results/hold.json]
    python benchmarks/hold.py --episodes 4 --blind-episodes 2 --out /tmp/hold.json   # a check that it runs

Writes the JSON file (commit, dataset version, load average at start and end) and prints
a summary. Run it on a quiet machine (``flock /tmp/dyana-bench.lock python benchmarks/hold.py``).
"""

from __future__ import annotations

import argparse
import collections
import datetime
import json
import os
import sys
import time
from pathlib import Path

import bench_setup
import numpy as np

from generators import motion
from generators.ground_truth import plan
from generators.hand import REST_JOINTS
from generators.hold import HoldResult, hold_test
from generators.hold_episode import episode_hold, palm_velocity
from generators.hold_grasp import closing_angles, hover_palm, resting_pose
from generators.hold_params import PENETRATION_TOLERANCE
from generators.recipe import spec_for
from pipeline.loop.rollout import task_for
from pipeline.loop.spaces import PALM_HIGH, PALM_LOW
from pipeline.policies.blind import BlindPolicy, CentrePolicy, FittedPolicy, SweepPolicy
from schemas.events import grasp_closed
from schemas.objects import OBJECTS
from schemas.scene import PALM_REST
from schemas.spec import EpisodeSpec
from schemas.versions import DATASET_VERSION, FPS

RESULT = Path(bench_setup.HERE) / "results" / "hold.json"
SPEED_BINS = (0.0, 1.0, 2.0, 4.0, float("inf"))


class FirstSeenExact(BlindPolicy):
    """``blind-first-seen`` with a perfect locator: over the object's first position, waits."""

    name = "blind-first-seen"

    def __init__(self, goal_xz: tuple[float, float]) -> None:
        super().__init__()
        self._goal_xz = goal_xz

    def target(self, t, obs):
        return np.array([self._goal_xz[0], self._hover, self._goal_xz[1]])


def play(policy, spec: EpisodeSpec) -> tuple[np.ndarray, np.ndarray]:
    """Palm poses and joint angles of ``policy`` in the kinematic stand-in, up to the frame
    the grasp closes (the environment ends the episode there) or the horizon."""
    policy.reset(task_for(spec, 224, False, spec.acting_horizon))
    rest = np.array(PALM_REST, dtype=np.float32)
    palm, joints = [rest.copy()], [REST_JOINTS.astype(np.float32)]
    for _ in range(spec.observe_frames):
        palm.append(rest.copy())
        joints.append(REST_JOINTS.astype(np.float32))
    grasp = plan(spec)[0].grasp_angles
    last = spec.observe_frames + spec.acting_horizon
    while len(palm) - 1 < last:
        obs = {"palm_pose": palm[-1], "joint_angles": joints[-1], "frame_index": len(palm) - 1}
        act = np.asarray(policy.act(obs), dtype=np.float32).astype(np.float64)
        xyz = np.clip(act[:3], PALM_LOW, PALM_HIGH).astype(np.float32)
        palm.append(np.concatenate([xyz, rest[3:]]))
        joints.append(act[3:].astype(np.float32))
        if grasp_closed(joints[-1], grasp):
            break
    return np.array(palm, dtype=np.float64), np.array(joints, dtype=np.float64)


def summary(rows: list[dict], key: str) -> dict:
    groups: dict[str, list[bool]] = collections.defaultdict(list)
    for row in rows:
        groups[str(row[key])].append(row["held"])
    return {k: {"n": len(v), "held": int(sum(v)), "rate": round(sum(v) / len(v), 4)} for k, v in sorted(groups.items())}


def speed_bin(speed: float) -> str:
    for lo, hi in zip(SPEED_BINS, SPEED_BINS[1:]):
        if lo <= speed < hi:
            return f"[{lo:g}, {hi:g})"
    return "nan"


def as_row(spec: EpisodeSpec, frame: int, result: HoldResult) -> dict:
    return {"index": spec.episode_index, "object": spec.object, "motion_type": spec.motion_type,
            "setting": spec.intercept_setting, "hand": spec.hand, "frame": frame, "held": result.held,
            "slip": round(result.slip, 4), "rise": round(result.rise, 4), "contacts": result.contacts,
            "penetration": round(result.penetration, 4)}


def ground_truth(specs: list[EpisodeSpec]) -> tuple[list[dict], list[HoldResult], list[float], dict]:
    rows, results, cpu, oracle, open_, beside = [], [], [], [], [], []
    for spec in specs:
        hp, poses, velocity = plan(spec)
        t0 = time.process_time()
        out = episode_hold(spec, hp.palm_pose, hp.joint_angles)
        cpu.append(time.process_time() - t0)
        assert out is not None, f"episode {spec.index}: the ground truth never closes"
        frame, result = out
        results.append(result)
        row = as_row(spec, frame, result)
        row["speed"] = round(float(np.linalg.norm(velocity[frame])), 3)
        row["speed_bin"] = speed_bin(row["speed"])
        rows.append(row)
        f32 = episode_hold(spec, hp.palm_pose.astype(np.float32), hp.joint_angles.astype(np.float32))
        oracle.append(bool(f32 is not None and f32[1].held))
        t = np.array([frame / float(FPS)])
        spin = motion.object_angular_velocity(spec.motion, spec.object, spec.object_size, t)[0]
        common = (spec.object, spec.object_size, spec.hand)
        pv = palm_velocity(hp.palm_pose, frame)
        open_.append(hold_test(*common, hp.palm_pose[frame], pv, REST_JOINTS, poses[frame], velocity[frame], spin).held)
        shifted = hp.palm_pose[frame] + np.array([1.0, 0, 0, 0, 0, 0])
        beside.append(hold_test(*common, shifted, pv, hp.joint_angles[frame], poses[frame], velocity[frame], spin).held)
    n = len(specs)
    extra = {"oracle": {"n": n, "held": int(sum(oracle)), "rate": round(sum(oracle) / n, 4)},
             "controls": {"open": {"n": n, "held": int(sum(open_))}, "beside": {"n": n, "held": int(sum(beside))}}}
    return rows, results, cpu, extra


def blind(specs: list[EpisodeSpec]) -> dict:
    out = {}
    makers = {"blind-centre": lambda s: CentrePolicy(), "blind-sweep": lambda s: SweepPolicy(),
              "blind-fitted": lambda s: FittedPolicy(),
              "blind-first-seen": lambda s: FirstSeenExact(tuple(plan(s)[1][0, [0, 2]]))}
    for name, make in makers.items():
        closed = held = 0
        cases = []
        for spec in specs:
            palm, joints = play(make(spec), spec)
            res = episode_hold(spec, palm, joints)
            closed += res is not None
            held += bool(res is not None and res[1].held)
            if res is not None and (res[1].held or res[1].penetration > 0.0):
                cases.append(as_row(spec, res[0], res[1]))
        out[name] = {"n": len(specs), "closed": closed, "held": held, "rate": round(held / len(specs), 4),
                     "held_or_starting_inside": cases}
    return out


#: Palm offsets from the ground truth's hover point (x, y, z) tried by :func:`placements`;
#: y = -0.23 rests the palm on the object's top.
OFFSETS_X = (0.0, 0.2, 0.4)
OFFSETS_Y = (0.0, -0.1, -0.23)
OFFSETS_Z = (-0.6, -0.45, -0.3, -0.15, 0.0)


def placements() -> dict:
    """Which palm placements of this hand (palm down, right hand) hold each object at rest
    at its nominal size, fingers closed along their synergies until they touch it."""
    out = {}
    for name in OBJECTS:
        size = OBJECTS[name].nominal_size
        held = []
        for dx in OFFSETS_X:
            for dy in OFFSETS_Y:
                for dz in OFFSETS_Z:
                    palm = hover_palm(name, size, (dx, dy, dz))
                    joints = closing_angles(name, size, "right", palm)
                    r = hold_test(name, size, "right", palm, np.zeros(3), joints, resting_pose(name, size),
                                  np.zeros(3), np.zeros(3))
                    if r.held:
                        held.append([dx, dy, dz])
        out[name] = {"tried": len(OFFSETS_X) * len(OFFSETS_Y) * len(OFFSETS_Z), "held": len(held),
                     "holding_offsets": held}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--slice", default="test-1k")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--blind-episodes", type=int, default=200)
    parser.add_argument("--no-placements", action="store_true", help="skip the placement grid (495 tests)")
    parser.add_argument("--out", type=Path, default=RESULT)
    args = parser.parse_args(argv)
    load_start = os.getloadavg()
    started = datetime.datetime.now(datetime.UTC)
    specs = [spec_for(args.slice, i) for i in range(args.episodes)]
    wall = time.perf_counter()
    rows, results, cpu, extra = ground_truth(specs)
    again = [episode_hold(s, plan(s)[0].palm_pose, plan(s)[0].joint_angles) for s in specs[:20]]
    same = all(a is not None and a[1] == r for a, r in zip(again, results))
    blind_rates = blind(specs[: args.blind_episodes])
    grid = None if args.no_placements else placements()
    frames = float(np.mean([s.num_frames for s in specs]))
    cpu_arr = np.array(cpu)
    failures = [r for r in rows if not r["held"]]
    record = {
        "date_utc": started.strftime("%Y-%m-%d %H:%M"),
        "commit": bench_setup_commit(),
        "dataset_version": DATASET_VERSION,
        "cores": os.cpu_count(),
        "load_average_start": [round(x, 2) for x in load_start],
        "slice": args.slice,
        "episodes": len(specs),
        "ground_truth": {"n": len(rows), "held": sum(r["held"] for r in rows),
                         "rate": round(sum(r["held"] for r in rows) / len(rows), 4),
                         "by_object": summary(rows, "object"), "by_motion_type": summary(rows, "motion_type"),
                         "by_setting": summary(rows, "setting"), "by_hand": summary(rows, "hand"),
                         "by_speed": summary(rows, "speed_bin"),
                         "failure_slip_median": float(np.median([r["slip"] for r in failures])) if failures else None,
                         "penetration_max": max(r["penetration"] for r in rows),
                         "starting_inside_by_object": {k: sum(r["penetration"] > PENETRATION_TOLERANCE for r in rows
                                                              if r["object"] == k) for k in OBJECTS},
                         "failure_contacts_at_end": dict(collections.Counter(r["contacts"] for r in failures)),
                         "held_examples": [r for r in rows if r["held"]][:10],
                         "failure_examples": failures[:10]},
        **extra,
        "blind": blind_rates,
        "placements": grid,
        "cost": {"cpu_s_mean": round(float(cpu_arr.mean()), 5), "cpu_s_p95": round(float(np.quantile(cpu_arr, 0.95)), 5),
                 "cpu_s_max": round(float(cpu_arr.max()), 5), "frames_per_episode_mean": round(frames, 2),
                 "cpu_s_per_frame": round(float(cpu_arr.mean()) / frames, 6)},
        "determinism": {"repeated": len(again), "identical": same},
        "wall_s": round(time.perf_counter() - wall, 1),
        "load_average_end": [round(x, 2) for x in os.getloadavg()],
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
    print(json.dumps({k: record[k] for k in ("ground_truth", "oracle", "controls", "blind", "cost", "determinism")})[:3000])
    return 0


def bench_setup_commit() -> str | None:
    from catalog.store.manifest import git_commit

    return git_commit(bench_setup.ROOT)


if __name__ == "__main__":
    sys.exit(main())
