"""Which ground-truth grasp holds? The hold test (issue 38's S_hold) of each grasp design.

A grasp design (:class:`generators.grasp.GraspDesign`: the hand geometry, the hover, the
synergy, how lying cylinders and boxes are grasped) is planned on the slice's episodes
with :func:`generators.ground_truth.plan` and tested from its first closed frame
(:func:`generators.hold_episode.episode_hold`). For each design in ``--designs``:

- ``ground_truth``: held / accepted / refused (the planner's InfeasibleError counts as a
  failure: every spec needs a ground truth), by object, motion type, interception
  setting and hand; every failure (slip, rise, contacts, penetration) and refusal reason;
- ``oracle``: the same plan's float32 states (what the oracle reaches through the
  environment); ``controls``: the closed frame's palm with the fingers open, and the
  closed hand 1 unit to the side;
- ``limits``: the ground truth against the hand body's limits (:mod:`generators.hand_body`):
  the fastest palm speed and acceleration, joint speed, the deepest finger capsule in the
  table, and the fastest palm turn;
- ``blind``: the four blind policies played in a kinematic stand-in (as
  ``benchmarks/hold.py``), closing to the design's fist (its synergy's end) and
  judged closed against the design's ground-truth grasp, on the first
  ``--blind-episodes`` episodes; with a wrist-reflex design the stand-in turns the palm by
  the reflex (:mod:`generators.wrist`) every frame, and ``turned`` counts the episodes
  it turned in;
- ``reflex_exact`` (wrist-reflex designs): the lying-cylinder plans whose recorded
  (float32) headings the reflex recomputes bit for bit from the recorded states;
  ``body_exact``: the plans whose actions, stepped through the hand body built for the
  design (:class:`generators.hand_body.HandBody`, its reflex on), reach every recorded
  state (palm, joints, heading) bit for bit, what the oracle reaches in the closed loop;
- ``at_rest``: each object at rest at 0.85, 1 and 1.15 of its nominal size, in the
  canonical placement, grasped as the design grasps it.

    python benchmarks/hold_grasp_design.py [--episodes 200] [--start 0] [--blind-episodes 50]
        [--designs splayed,opposed] [--out benchmarks/results/hold_grasp_design.json]

Writes one JSON file (commit, dataset version, load average at start and end).
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
from hold import FirstSeenExact

from generators import motion
from generators.grasp import DESIGNS, GraspDesign, grasp_angles, grasp_hover
from generators.ground_truth import episode_grasp, plan
from generators.hand import FINGER_RADII, REST_JOINTS, chain_frames
from generators.hand_body import HandBody
from generators.hold import hold_test
from generators.hold_episode import episode_hold, palm_velocity
from generators.hold_grasp import resting_pose
from generators.recipe import spec_for
from generators.wrist import wrist_headings, wrist_step
from pipeline.loop.rollout import task_for
from pipeline.loop.spaces import PALM_HIGH, PALM_LOW
from pipeline.policies.blind import FIST, CentrePolicy, FittedPolicy, SweepPolicy
from schemas.errors import InfeasibleError
from schemas.events import grasp_closed
from schemas.objects import OBJECTS, object_category
from schemas.scene import PALM_REST
from schemas.spec import EpisodeSpec
from schemas.versions import DATASET_VERSION, FPS

RESULT = Path(bench_setup.HERE) / "results" / "hold_grasp_design.json"
KEYS = ("object", "motion_type", "setting", "hand")


def tally(rows: list[dict], key: str) -> dict:
    """held / accepted / refused per value of ``key``."""
    out: dict[str, dict[str, int]] = collections.defaultdict(lambda: {"held": 0, "accepted": 0, "refused": 0})
    for row in rows:
        cell = out[str(row[key])]
        cell["refused" if row["refused"] else "accepted"] += 1
        cell["held"] += bool(row["held"])
    return dict(sorted(out.items()))


def limits(design: GraspDesign, spec: EpisodeSpec, palm_pose: np.ndarray, joints: np.ndarray) -> dict:
    """The ground truth's peak palm speed (units/s), acceleration (units/s^2), joint speed
    (rad/s) and palm turn rate (rad/s); how deep its finger segments go under the table as
    the hand body's cylinders (``table_depth``, :mod:`generators.hand_urdf`) and as the hold
    test's capsules (``table_depth_capsule``)."""
    a = spec.observe_frames
    step = np.diff(palm_pose[a:, :3], axis=0) * FPS
    pos = chain_frames(palm_pose, joints, spec.hand, design.hand)[0]
    start, end, radius = pos[:, :, :3], pos[:, :, 1:], FINGER_RADII[None, :, None]
    d_y = (end - start)[..., 1] / np.linalg.norm(end - start, axis=-1)
    cylinder = np.minimum(start[..., 1], end[..., 1]) - radius * np.sqrt(np.clip(1.0 - d_y**2, 0.0, 1.0))
    return {"palm_speed": float(np.linalg.norm(step, axis=1).max()),
            "palm_acceleration": float(np.linalg.norm(np.diff(step, axis=0), axis=1).max() * FPS),
            "joint_speed": float(np.abs(np.diff(joints, axis=0)).max() * FPS),
            "palm_turn_rate": float(np.abs(np.diff(palm_pose[:, 4])).max() * FPS),
            "table_depth": float(max(0.0, -cylinder.min())),
            "table_depth_capsule": float(max(0.0, -(pos[..., 1] - radius).min()))}


def through_body(body: HandBody, spec: EpisodeSpec, hp, poses: np.ndarray) -> int | None:
    """The first frame at which the plan's actions, stepped through ``body``, miss the
    plan's recorded state (None: every frame reached bit for bit)."""
    body.reset(spec.hand, spec.object, spec.object_size, spec.obstacles)
    action, state, joints, obj = (np.asarray(x, np.float32).astype(np.float64)
                                  for x in (hp.action, hp.palm_pose, hp.joint_angles, poses))
    for t in range(spec.observe_frames, spec.num_frames - 1):
        palm, q = body.step(action[t, :3], action[t, 3:], obj[t + 1])
        if not (np.array_equal(palm, state[t + 1, :3]) and np.array_equal(q, joints[t + 1])
                and body.heading == state[t + 1, 4]):
            return t + 1
    return None


def ground_truth(design: GraspDesign, specs: list[EpisodeSpec]) -> dict:
    rows, oracle, open_, beside, peaks, cpu = [], [], [], [], collections.defaultdict(float), []
    exact, body_exact, body_off = [0, 0], 0, []
    body = HandBody((PALM_LOW, PALM_HIGH), design) if design.wrist_reflex else None
    for spec in specs:
        row = {"index": spec.episode_index, **{k: getattr(spec, "intercept_setting" if k == "setting" else k)
                                                for k in KEYS}, "refused": None, "held": False}
        rows.append(row)
        try:
            hp, poses, velocity = plan(spec, design)
        except InfeasibleError as exc:
            row["refused"] = str(exc)
            continue
        if design.wrist_reflex and object_category(spec.object).lying:
            f32 = [np.asarray(x, np.float32).astype(np.float64) for x in (hp.palm_pose, hp.joint_angles, poses)]
            turned = wrist_headings(f32[0][:, :3], f32[1], f32[2], spec.object, np.asarray(design.synergy_end))
            exact[0] += bool(np.array_equal(turned, f32[0][:, 4]))
            exact[1] += 1
        if body is not None:
            off = through_body(body, spec, hp, poses)
            body_exact += off is None
            if off is not None:
                body_off.append({"index": spec.episode_index, "object": spec.object, "frame": off})
        for name, value in limits(design, spec, hp.palm_pose, hp.joint_angles).items():
            peaks[name] = max(peaks[name], value)
        t0 = time.process_time()
        out = episode_hold(spec, hp.palm_pose, hp.joint_angles, design)
        cpu.append(time.process_time() - t0)
        if out is None:
            row["refused"] = "the ground truth never closes"
            continue
        frame, result = out
        row.update(frame=frame, held=result.held, slip=round(result.slip, 4), rise=round(result.rise, 4),
                   contacts=result.contacts, penetration=round(result.penetration, 4),
                   hover=round(grasp_hover(spec.object, spec.object_size, spec.hand, design), 3))
        f32 = episode_hold(spec, hp.palm_pose.astype(np.float32), hp.joint_angles.astype(np.float32), design)
        oracle.append(bool(f32 is not None and f32[1].held))
        t = np.array([frame / float(FPS)])
        spin = motion.object_angular_velocity(spec.motion, spec.object, spec.object_size, t)[0]
        args = (spec.object, spec.object_size, spec.hand)
        pv = palm_velocity(hp.palm_pose, frame)
        state = (poses[frame], velocity[frame], spin, design.hand)
        open_.append(hold_test(*args, hp.palm_pose[frame], pv, REST_JOINTS, *state).held)
        shifted = hp.palm_pose[frame] + np.array([1.0, 0, 0, 0, 0, 0])
        beside.append(hold_test(*args, shifted, pv, hp.joint_angles[frame], *state).held)
    n = len(rows)
    held = sum(bool(r["held"]) for r in rows)
    refused = sum(r["refused"] is not None for r in rows)
    return {
        "n": n, "held": held, "accepted": n - refused, "refused": refused, "rate": round(held / n, 4),
        **{f"by_{k}": tally(rows, k) for k in KEYS},
        "oracle": {"n": n, "held": int(sum(oracle)), "rate": round(sum(oracle) / n, 4)},
        "controls": {"open": int(sum(open_)), "beside": int(sum(beside)), "of": len(open_)},
        **({"reflex_exact": {"exact": exact[0], "of": exact[1]},
            "body_exact": {"exact": body_exact, "of": n - refused, "off": body_off}} if design.wrist_reflex else {}),
        "limits": {k: round(v, 4) for k, v in peaks.items()},
        "hold_test_cpu_ms": round(1000 * float(np.mean(cpu)), 1) if cpu else None,
        "failures": [r for r in rows if not r["held"]],
    }


def play(policy, spec: EpisodeSpec, design: GraspDesign) -> tuple[np.ndarray, np.ndarray]:
    """``benchmarks/hold.py``'s kinematic stand-in, the fingers closing along the design's
    synergy as far as the policy closes its fist, until they pass the design's grasp criterion."""
    policy.reset(task_for(spec, 224, False, spec.acting_horizon))
    rest = np.array(PALM_REST, dtype=np.float32)
    palm, joints = [rest.copy()] * (spec.observe_frames + 1), [REST_JOINTS.astype(np.float32)] * (spec.observe_frames + 1)
    grasp = episode_grasp(spec, design)
    end = np.asarray(design.synergy_end)
    last = spec.observe_frames + spec.acting_horizon
    poses = motion.object_pose(spec.motion, spec.object, spec.object_size, np.arange(last + 1) / float(FPS))[0]
    poses = poses.astype(np.float32).astype(np.float64)
    while len(palm) - 1 < last:
        obs = {"palm_pose": palm[-1], "joint_angles": joints[-1], "frame_index": len(palm) - 1}
        act = np.asarray(policy.act(obs), dtype=np.float32).astype(np.float64)
        fraction = float(np.max(act[3:] / FIST, where=FIST > 0, initial=0.0))
        joints.append((fraction * end).astype(np.float32))
        new = np.concatenate([np.clip(act[:3], PALM_LOW, PALM_HIGH).astype(np.float32), rest[3:]])
        if design.wrist_reflex:
            new[4] = wrist_step(float(palm[-1][4]), new[:3].astype(np.float64), joints[-1].astype(np.float64),
                                poses[len(palm)], spec.object, end)
        palm.append(new)
        if grasp_closed(joints[-1], grasp):
            break
    return np.array(palm, dtype=np.float64), np.array(joints, dtype=np.float64)


def blind(design: GraspDesign, specs: list[EpisodeSpec]) -> dict:
    makers = {"blind-centre": lambda s: CentrePolicy(), "blind-sweep": lambda s: SweepPolicy(),
              "blind-fitted": lambda s: FittedPolicy(),
              "blind-first-seen": lambda s: FirstSeenExact(tuple(plan(s)[1][0, [0, 2]]))}
    out = {}
    for name, make in makers.items():
        closed = held = turned = 0
        for spec in specs:
            palm, joints = play(make(spec), spec, design)
            res = episode_hold(spec, palm, joints, design)
            closed += res is not None
            held += bool(res is not None and res[1].held)
            turned += bool(np.any(palm[:, 4] != 0.0))
        out[name] = {"n": len(specs), "closed": closed, "held": held, "turned": turned}
    return out


def at_rest(design: GraspDesign) -> dict:
    out = {}
    still = np.zeros(3)
    for name, cat in OBJECTS.items():
        cells = []
        for factor in (0.85, 1.0, 1.15):
            size = cat.nominal_size * factor
            palm = np.array([0.0, 2.0 * cat.half_height(size) + grasp_hover(name, size, "right", design), 0, 0, 0, 0])
            joints = grasp_angles(name, size, "right", design)
            cells.append(bool(hold_test(name, size, "right", palm, still, joints, resting_pose(name, size), still, still,
                                        design.hand).held))
        out[name] = cells
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--slice", default="test-1k")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--blind-episodes", type=int, default=50)
    parser.add_argument("--designs", default=",".join(DESIGNS))
    parser.add_argument("--out", type=Path, default=RESULT)
    args = parser.parse_args(argv)
    load_start = os.getloadavg()
    started = datetime.datetime.now(datetime.UTC)
    t0 = time.perf_counter()
    specs = [spec_for(args.slice, i) for i in range(args.start, args.start + args.episodes)]
    runs = {}
    for name in args.designs.split(","):
        design = DESIGNS[name]
        runs[name] = {"ground_truth": ground_truth(design, specs), "blind": blind(design, specs[: args.blind_episodes]),
                      "at_rest_held_at_0.85_1_1.15": at_rest(design)}
        gt = runs[name]["ground_truth"]
        print(f"{name}: held {gt['held']} / accepted {gt['accepted']} / refused {gt['refused']} of {gt['n']}; "
              f"oracle {gt['oracle']['held']}; blind {[b['held'] for b in runs[name]['blind'].values()]}", flush=True)
    from catalog.store.manifest import git_commit

    lying = sorted(n for n, c in OBJECTS.items() if object_category(n).lying)
    record = {"date_utc": started.strftime("%Y-%m-%d %H:%M"), "commit": git_commit(bench_setup.ROOT),
              "dataset_version": DATASET_VERSION, "slice": args.slice, "episodes": [args.start, args.start + args.episodes],
              "blind_episodes": args.blind_episodes, "cores": os.cpu_count(), "lying_cylinders": lying,
              "load_average_start": [round(x, 2) for x in load_start], "designs": runs,
              "wall_s": round(time.perf_counter() - t0, 1), "load_average_end": [round(x, 2) for x in os.getloadavg()]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
