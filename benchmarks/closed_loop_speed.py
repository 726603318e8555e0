"""The closed loop's speed: the predictive policy's first action, and evaluation against building.

- ``first_act``: the ``predictive`` policy's first ``act`` on each of the first
  ``--episodes`` test-1k episodes at ``--resolution`` px. That call localises the object
  in every frame of the observe window (up to 100 frames) and fits the motion, so it is
  the loop's longest. Each episode's call is timed ``--repeats`` times (a fresh
  ``reset`` each time; the same action every time) and its best CPU and wall times
  kept, against other users' load; then the median, p95 and max over the episodes.
  In this process, one thread.
- ``build`` and ``eval``: ``pipeline build --specs`` of the same episodes' specs and
  ``pipeline eval --policy still|predictive`` on them, each a fresh process with
  ``--workers`` workers (default 1), timed by wall clock including interpreter and
  cluster start-up; episodes/s and frames/s (recorded frames: an evaluated episode
  ends at its grasp, so it may record fewer frames than the built one), and each
  evaluation's rates over the build's. The CPU seconds of each command (its process
  and its workers, from ``getrusage``) are recorded too: on a shared machine their
  ratios move less than the wall clock's.

- ``profile`` (``--profile``): where evaluation spends CPU beyond building, in this
  process (``workers=0``, one thread but the policy's): after an untimed warm-up of one
  episode each, the build of the episodes' specs and ``still``'s evaluation of the same
  episodes, each with its stages timed by ``benchmarks/build.py``'s clock (CPU ms per
  recorded frame), plus the loop's own stages: per-step hand measures (forward kinematics
  and distances), JPEG decoding of what the policy sees, the observation, the policy call
  (the hand-off to its thread), and the rest of each layer: the simulator's reset and step,
  the recorder, the rollout loop; and the physics of dataset 5.0.0: the hand body's
  pybullet steps (limits, collisions, the wrist reflex) and the hold test the shard's
  counts run on each closed episode. ``eval_over_build`` = the evaluation's frames per CPU
  second over the build's (``frames_per_cpu_s_vs_build`` of ``still``, without process
  and cluster start-up). ``still`` never closes its hand, so the same episodes are also
  evaluated with ``oracle`` (``eval_oracle``: every episode closes and is hold-tested);
  ``physics_share`` is hand body plus hold test over each evaluation's CPU per frame,
  against ``physics_target`` (0.25). The profile runs ``--profile-repeats`` times (default
  3), each in a fresh process so that no cache of an earlier run (the hold test's memory,
  the ground truth's) carries over: each stage is the median over the repeats,
  ``physics_share`` the median of the repeats' shares (each in ``physics_share_repeats``),
  and the repeats must write the same bytes.

Prints a summary on stderr and, as the last line, one JSON object. The load average
(``os.getloadavg``) is recorded before and after: the machine may be shared.

    python benchmarks/closed_loop_speed.py                   # 50 episodes, ~2 minutes
    python benchmarks/closed_loop_speed.py --episodes 5 --repeats 1 --no-throughput
    python benchmarks/closed_loop_speed.py --episodes 32 --profile --no-throughput
"""

from __future__ import annotations

import os

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

SLICE = "test-1k"
POLICIES = ("still", "predictive")
#: The closed loop's own stages (beyond a build's) and the functions they time, as the loop calls them.
LOOP_STAGES = ("hand measures", "JPEG decode", "observation", "policy call", "hand body", "hold test", "env step",
               "recorder", "rollout")
#: The physics the hand body and the hold test add (issue 38: together <= 25% of a frame's CPU).
PHYSICS = ("hand body", "hold test")
#: What the profile runs: the build, then still's and oracle's evaluations of the same episodes.
PROFILED = ("build", "eval", "eval_oracle")
PHYSICS_TARGET = 0.25
LOOP_HOOKS = (
    ("episode stage", "pipeline.loop.wrappers", "assemble_frames"),  # the recording's frames
    ("episode stage", "pipeline.loop.env", "object_pose"),  # the object's motion, at reset
    ("episode stage", "pipeline.loop.env", "grasp_angles"),
    ("hand measures", "pipeline.loop.env", "measure_hand"),  # per step, for the observation and info
    ("JPEG encode", "pipeline.loop.env", "encode_jpeg"),
    ("JPEG encode", "pipeline.loop.env", "encode_bgr_jpeg"),
    ("JPEG decode", "pipeline.loop.env", "decode_jpeg"),
    ("observation", "pipeline.loop.env:DyanaEnv", "_observation"),
    ("policy call", "pipeline.loop.rollout", "call_policy"),
    ("hand body", "generators.hand_body:HandBody", "__init__"),  # pybullet: limits, collisions, the wrist
    ("hand body", "generators.hand_body:HandBody", "reset"),
    ("hand body", "generators.hand_body:HandBody", "step"),
    ("hold test", "scoring.hold", "hold_frames"),  # the shard's counts score S_hold in the worker
    # the rest of each layer, exclusive of the stages above: the simulator's reset/step/frame,
    # the recorder and the protocol wrappers, the rollout loop
    ("env step", "pipeline.loop.env:DyanaEnv", "reset"),
    ("env step", "pipeline.loop.env:DyanaEnv", "step"),
    ("env step", "pipeline.loop.env:DyanaEnv", "_simulate"),
    ("env step", "pipeline.loop.env:DyanaEnv", "_info"),
    ("recorder", "pipeline.loop.wrappers:RecordEpisode", "reset"),
    ("recorder", "pipeline.loop.wrappers:RecordEpisode", "step"),
    ("recorder", "pipeline.loop.wrappers:RecordEpisode", "recording"),
    ("rollout", "pipeline.jobs.evaluate", "run_episode"),
    ("rollout", "pipeline.loop.rollout", "run_chunk"),
)


def load_average() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def first_act(episodes: int, resolution: int, repeats: int) -> dict:
    """Best-of-``repeats`` CPU and wall seconds of the predictive policy's first act per
    episode, summarised over the first ``episodes`` test-1k episodes; ``actions_sha256``
    digests the first actions (the same code gives the same digest)."""
    from generators.recipe import spec_for
    from pipeline.loop.env import horizon
    from pipeline.loop.rollout import task_for
    from pipeline.loop.wrappers import loop_env
    from pipeline.policies.predictive import PredictivePolicy

    env = loop_env(resolution)
    policy = PredictivePolicy()
    cpu, wall, window = [], [], []
    digest = hashlib.sha256()
    for i in range(episodes):
        spec = spec_for(SLICE, i)
        obs, _ = env.reset(options={"spec": spec})
        task = task_for(spec, env.resolution, policy.privileged, horizon(spec))
        best_cpu = best_wall = float("inf")
        for _ in range(repeats):
            policy.reset(task)
            c0, w0 = time.process_time(), time.perf_counter()
            action = policy.act(obs)
            best_cpu = min(best_cpu, time.process_time() - c0)
            best_wall = min(best_wall, time.perf_counter() - w0)
        cpu.append(best_cpu)
        wall.append(best_wall)
        images = obs.get("observe_images")
        window.append(0 if images is None else len(images))
        digest.update(np.asarray(action, dtype=np.float32).tobytes())
    c, w = np.array(cpu), np.array(wall)
    return {
        "episodes": episodes,
        "repeats": repeats,
        "resolution": resolution,
        "cpu_median_s": round(float(np.median(c)), 4),
        "cpu_p95_s": round(float(np.percentile(c, 95)), 4),
        "cpu_max_s": round(float(c.max()), 4),
        "wall_median_s": round(float(np.median(w)), 4),
        "wall_p95_s": round(float(np.percentile(w, 95)), 4),
        "wall_max_s": round(float(w.max()), 4),
        "observe_frames_median": float(np.median(window)),
        "observe_frames_max": int(max(window)),
        "actions_sha256": digest.hexdigest(),
    }


def run_command(argv: list[str], out: Path | None = None) -> tuple[float, float]:
    """Wall and CPU seconds (user + system of the process and every child it waited
    for) of ``python -m ARGV...`` run from this repository as a fresh process; its
    stdout goes to ``out``."""
    env = {**os.environ, "PYTHONPATH": bench_setup.ROOT}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    with open(out if out is not None else os.devnull, "w") as sink:
        done = subprocess.run([sys.executable, "-m", *argv], cwd=bench_setup.ROOT, env=env, stdout=sink,
                              stderr=subprocess.PIPE, text=True)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} exited with {done.returncode}: {done.stderr.strip()[-500:]}")
    return seconds, (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)


def _rates(timing: tuple[float, float], folder: Path) -> dict:
    seconds, cpu = timing
    manifest = json.loads((folder / "catalog.json").read_text())
    return {
        "seconds": round(seconds, 3),
        "cpu_seconds": round(cpu, 3),
        "episodes": manifest["episodes"],
        "frames": manifest["frames"],
        "episodes_per_s": round(manifest["episodes"] / seconds, 3),
        "frames_per_s": round(manifest["frames"] / seconds, 1),
        "frames_per_cpu_s": round(manifest["frames"] / cpu, 1),
        "hash": manifest["hash"],
    }


def throughput(episodes: int, resolution: int, workers: int, tmp: Path) -> dict:
    """``pipeline build --specs`` of the episodes' specs and ``pipeline eval`` of each of
    :data:`POLICIES` on the same episodes, timed in turn."""
    specs = tmp / "specs.jsonl"
    run_command(["pipeline.cli_catalog", "specs", SLICE, "--episodes", str(episodes)], out=specs)
    common = ["--workers", str(workers), "--resolution", str(resolution), "--quiet"]
    timing = run_command(["pipeline.cli", "build", "--specs", str(specs), "--out", str(tmp / "build"), *common])
    build = _rates(timing, tmp / "build" / SLICE)
    result = {"build": build, "eval": {}}
    for name in POLICIES:
        out = tmp / f"eval-{name}"
        timing = run_command(["pipeline.cli", "eval", "--policy", name, "--slice", SLICE, "--episodes", str(episodes),
                              "--out", str(out), *common])
        rates = _rates(timing, out)
        rates["episodes_per_s_vs_build"] = round(rates["episodes_per_s"] / build["episodes_per_s"], 3)
        rates["frames_per_s_vs_build"] = round(rates["frames_per_s"] / build["frames_per_s"], 3)
        rates["frames_per_cpu_s_vs_build"] = round(rates["frames_per_cpu_s"] / build["frames_per_cpu_s"], 3)
        result["eval"][name] = rates
    return result


def stage_profile(episodes: int, resolution: int, tmp: Path) -> dict:
    """CPU ms per recorded frame by stage of an in-process build of the first ``episodes``
    test-1k specs and of ``still``'s and ``oracle``'s evaluations of them (module docstring)."""
    from build import HOOKS, STAGES, Hook, StageClock, close_renderers, hooked

    from generators.recipe import spec_for
    from pipeline.jobs.build import build
    from pipeline.jobs.evaluate import evaluate

    stages = STAGES + LOOP_STAGES
    hooks = HOOKS + tuple(Hook(*hook) for hook in LOOP_HOOKS)
    specs = tmp / "profile-specs.jsonl"
    specs.write_text("".join(spec_for(SLICE, i).to_json() + "\n" for i in range(episodes)))
    warm = tmp / "warm.jsonl"
    warm.write_text(spec_for(SLICE, 0).to_json() + "\n")
    build(None, tmp / "warm-build", specs_path=str(warm), workers=0, resolution=resolution, progress=False)
    evaluate("still", SLICE, tmp / "warm-eval", episodes=1, workers=0, resolution=resolution, progress=False,
             summary=False)
    close_renderers()
    result: dict = {}
    for name in ("build", "eval", "eval_oracle"):
        clock = StageClock(stages)
        with hooked(clock, hooks):
            cpu = time.process_time()
            if name == "build":
                manifest = build(None, tmp / "profile-build", specs_path=str(specs), workers=0, resolution=resolution,
                                 progress=False)
            else:
                policy = "oracle" if name == "eval_oracle" else "still"
                manifest = evaluate(policy, SLICE, tmp / f"profile-{name}", episodes=episodes, workers=0,
                                    resolution=resolution, progress=False, summary=False)
            cpu = time.process_time() - cpu
        ms = {stage: 1000.0 * clock.totals[stage] / manifest.frames for stage in stages}
        ms["other"] = 1000.0 * (cpu - sum(clock.totals.values())) / manifest.frames
        result[name] = {"frames": manifest.frames, "cpu_seconds": cpu, "ms_per_frame": ms, "hash": manifest.hash}
    return result


def profile_median(episodes: int, resolution: int, repeats: int) -> dict:
    """:func:`stage_profile` run ``repeats`` times, each in a fresh process (no cache of an
    earlier repeat, such as the hold test's memory, carries over): each stage's median CPU ms
    per frame, each repeat's physics share and their median. The repeats must write the same bytes."""
    runs = []
    for repeat in range(repeats):
        out = subprocess.run([sys.executable, __file__, "--profile-once", "--episodes", str(episodes),
                              "--resolution", str(resolution)], check=True, capture_output=True, text=True)
        runs.append(json.loads(out.stdout.splitlines()[-1]))
        print(f"profile {repeat + 1}/{repeats}: " + ", ".join(
            f"{name} {runs[-1][name]['cpu_seconds']:.1f} CPU s" for name in PROFILED), file=sys.stderr)
    result: dict = {"repeats": repeats}
    for name in PROFILED:
        hashes = {run[name]["hash"] for run in runs}
        if len(hashes) != 1:
            raise SystemExit(f"profile: the repeats of {name} wrote different bytes: {sorted(hashes)}")
        ms = {stage: float(np.median([run[name]["ms_per_frame"][stage] for run in runs]))
              for stage in runs[0][name]["ms_per_frame"]}
        cpu = float(np.median([run[name]["cpu_seconds"] for run in runs]))
        frames = runs[0][name]["frames"]
        result[name] = {"frames": frames, "cpu_seconds": round(cpu, 3), "frames_per_cpu_s": round(frames / cpu, 1),
                        "ms_per_frame": {stage: round(v, 3) for stage, v in ms.items()}, "hash": hashes.pop()}
    result["eval_over_build"] = round(result["eval"]["frames_per_cpu_s"] / result["build"]["frames_per_cpu_s"], 3)
    shares = {name: [sum(run[name]["ms_per_frame"][s] for s in PHYSICS) / sum(run[name]["ms_per_frame"].values())
                     for run in runs] for name in ("eval", "eval_oracle")}
    result["physics_share"] = {name: round(float(np.median(v)), 3) for name, v in shares.items()}
    result["physics_share_repeats"] = {name: [round(x, 3) for x in v] for name, v in shares.items()}
    result["physics_target"] = PHYSICS_TARGET
    return result


def profile_lines(profile: dict) -> list[str]:
    build, ev = profile["build"]["ms_per_frame"], profile["eval"]["ms_per_frame"]
    oracle = profile["eval_oracle"]["ms_per_frame"]
    lines = [f"stage profile, in process, CPU ms per recorded frame ({profile['build']['frames']} built, "
             f"{profile['eval']['frames']} evaluated by still, {profile['eval_oracle']['frames']} by oracle):",
             f"{'stage':<16} {'build':>8} {'still':>8} {'still-build':>11} {'oracle':>8}"]
    for stage in build:
        lines.append(f"{stage:<16} {build[stage]:8.3f} {ev[stage]:8.3f} {ev[stage] - build[stage]:+11.3f} {oracle[stage]:8.3f}")
    total_b, total_e, total_o = sum(build.values()), sum(ev.values()), sum(oracle.values())
    lines.append(f"{'total':<16} {total_b:8.3f} {total_e:8.3f} {total_e - total_b:+11.3f} {total_o:8.3f}")
    lines.append(f"eval still / build, frames per CPU second: {profile['eval_over_build']:.3f}")
    shares = profile["physics_share"]
    each = profile["physics_share_repeats"]["eval_oracle"]
    lines.append(f"hand body + hold test, share of a frame's CPU (median of {profile['repeats']}): still "
                 f"{shares['eval']:.3f}, oracle {shares['eval_oracle']:.3f} (each: {', '.join(f'{x:.3f}' for x in each)}; "
                 f"target <= {profile['physics_target']})")
    return lines


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=50, help="first N test-1k episodes (default 50)")
    parser.add_argument("--repeats", type=int, default=3, help="first-act timings per episode, best kept")
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--workers", type=int, default=1, help="workers of each build and eval (default 1)")
    parser.add_argument("--no-throughput", action="store_true", help="time the first act only")
    parser.add_argument("--profile", action="store_true",
                        help="also profile an in-process build and still evaluation by stage")
    parser.add_argument("--profile-repeats", type=int, default=3,
                        help="profile runs, each a fresh process; each stage's median is reported (default 3)")
    parser.add_argument("--profile-once", action="store_true", help=argparse.SUPPRESS)  # one run, as JSON
    parser.add_argument("--no-first-act", action="store_true", help="skip the first-act timing")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.repeats < 1 or args.workers < 1 or args.profile_repeats < 1:
        parser.error("--episodes, --repeats, --workers and --profile-repeats must be >= 1")

    result: dict = {"benchmark": "closed_loop_speed", "slice": SLICE, "load_average_start": load_average()}
    if args.profile_once:
        with tempfile.TemporaryDirectory(prefix="dyana-closed-loop-profile-") as tmp:
            print(json.dumps(stage_profile(args.episodes, args.resolution, Path(tmp))))
        return {}
    if args.profile:
        result["profile"] = profile_median(args.episodes, args.resolution, args.profile_repeats)
        print("\n".join(profile_lines(result["profile"])), file=sys.stderr)
    if args.no_first_act:
        act = None
    else:
        act = first_act(args.episodes, args.resolution, args.repeats)
    if act is not None:
        print(f"first act (predictive, {args.episodes} episodes, best of {args.repeats}): CPU median "
              f"{act['cpu_median_s']:.3f} s, p95 {act['cpu_p95_s']:.3f} s, max {act['cpu_max_s']:.3f} s; wall median "
              f"{act['wall_median_s']:.3f} s, p95 {act['wall_p95_s']:.3f} s", file=sys.stderr)
        result["first_act"] = act
    if not args.no_throughput:
        with tempfile.TemporaryDirectory(prefix="dyana-closed-loop-") as tmp:
            rates = throughput(args.episodes, args.resolution, args.workers, Path(tmp))
        build = rates["build"]
        print(f"build: {build['episodes_per_s']:.2f} episodes/s, {build['frames_per_s']:.0f} frames/s "
              f"({build['frames']} frames in {build['seconds']:.1f} s, {build['cpu_seconds']:.1f} CPU s; "
              f"{args.workers} worker(s))", file=sys.stderr)
        for name, r in rates["eval"].items():
            print(f"eval {name}: {r['episodes_per_s']:.2f} episodes/s ({r['episodes_per_s_vs_build']:.2f}x the build), "
                  f"{r['frames_per_s']:.0f} frames/s ({r['frames_per_s_vs_build']:.2f}x; {r['frames']} frames in "
                  f"{r['seconds']:.1f} s, {r['cpu_seconds']:.1f} CPU s: {r['frames_per_cpu_s_vs_build']:.2f}x "
                  f"the build's frames per CPU second)", file=sys.stderr)
        result.update(rates, workers=args.workers)
    result["load_average_end"] = load_average()
    result.update({k: v for k, v in bench_setup.provenance().items() if k != "load_average"})
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
