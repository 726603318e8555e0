"""Pixel-free adversaries of S_loc, and candidate S_loc rules scored offline (issue 38).

**The adversaries** read no pixel and no privileged state: only the task (the text's
object and, where it names one, motion family; the interception setting's time; the
observe window's length; the horizon) and the hand's own ``palm_pose``/``frame_index``.
Their knowledge is the object paths of the *training* slices (``{linear,circular,
harmonic}-{fast,medium,slow}``, specs from :func:`generators.recipe.spec_for`, object
poses from :func:`generators.motion.object_pose`), never test-1k's: per episode, the
first :data:`POOL` training episodes of the same object, setting (and motion, when the
text names it), each path read at the acting frames (``observe_frames + t``). The palm
hovers at the named object's nominal top + ``PALM_HOVER`` and every planned step goes
through :func:`generators.hand_body.limit_palm`, so the body reaches it exactly.

=================  ====================================================================
``JumpPolicy``     (a) each frame, aims at the next-frame position of one training path
                   (a fixed shuffle, one path per frame); the body clips the move
``CoverPolicy``    (b) greedy cover: plans, at its first action, waypoints (path j at
                   frame s) that maximise newly covered paths per frame spent, a path
                   counting as covered once the planned palm was within 0.3 of it on
                   ``dwell`` consecutive frames; never closes the hand
``Dwell4Policy``   the same cover, a path covered only by 4 consecutive frames within 0.3
``ModePolicy``     follows the training path that, at some frame c (its choice), has the
                   most others within 0.3 on frames c-1..c+1, and closes the hand there
=================  ====================================================================

**The run** (``main``): each adversary and the built-ins (oracle, predictive, chase, still,
the four ``blind-*``) are run with ``python -m pipeline.cli eval`` (``--in-process``, one
worker) on test-1k's first ``--episodes`` at ``--resolution``; each run is scored with
``python -m scoring.cli eval --json`` and read back with :func:`scoring.io.load_run`;
:mod:`loc_rules` computes every candidate S_loc rule with a 95% Wilson interval. Writes
``benchmarks/results/blind_adversaries.json`` (commit, dataset version, load averages).
CPU-heavy: 60 episodes at 64 px took 485-1114 s per adversary (the cover plans for up to
10 s an episode) and 22-310 s per built-in, on 2 cores shared at load 5-9. Run it alone,
``nice python benchmarks/blind_adversaries.py``; ``--reuse`` scores the runs already in
``--runs`` (recorded with the same commands) without recording them again, and the JSON's
``seconds`` then lists only the runs recorded by that call.
"""

from __future__ import annotations

import abc
import argparse
import json
import os
import subprocess
import sys
import time
from functools import lru_cache

import numpy as np

try:
    import bench_setup  # noqa: F401  (run as a script: puts the repository first on sys.path)
except ModuleNotFoundError:  # imported by the closed loop as benchmarks.blind_adversaries
    pass

from generators.hand import REST_JOINTS
from generators.hand_body import limit_palm
from generators.motion import object_pose
from generators.recipe import MOTION_PHRASES, SETTINGS, spec_for
from pipeline.loop.env import horizon
from pipeline.policies.blind import FIST, hover_height, setting_of
from pipeline.policies.grip import closing_joints
from pipeline.policies.perception import object_from_text
from schemas.objects import object_category
from schemas.scene import LOC_TOLERANCE, MOTION_TYPES
from schemas.versions import DATASET_VERSION, FPS
from scoring.io import load_run
from scoring.metrics import wilson_interval

#: The repository's root (the runs and the scoring are run from it).
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: Training paths per episode's pool (same object, setting, and named motion).
POOL = 200
#: Training episodes scanned at most per slice while filling a pool.
SCAN = 4000
#: How far ahead (frames) the cover looks for its next waypoint.
LOOKAHEAD = 12
#: Waypoints tried per arrival frame (the most promising by the paths near them).
CANDIDATES = 12
#: A planned arrival counts when the simulated palm ends this close (XZ) to the waypoint.
ARRIVE = 0.1


def motion_named(text: str) -> str | None:
    """The motion family the task text names (the recipe's phrases), or None."""
    found = [kind for kind, phrase in MOTION_PHRASES.items() if phrase in str(text)]
    return found[0] if len(found) == 1 else None


@lru_cache(maxsize=64)
def training_pool(obj: str | None, setting: str, motion: str | None, horizon: int, count: int = POOL) -> np.ndarray:
    """(n, horizon, 2) XZ object paths of training episodes at their acting frames 0..horizon-1."""
    kinds = (motion,) if motion else MOTION_TYPES
    paths = []
    for i in range(SCAN):
        for kind in kinds:
            spec = spec_for(f"{kind}-{setting}", i)
            if obj is not None and spec.object != obj:
                continue
            times = (spec.observe_frames + np.arange(horizon, dtype=np.float64)) / FPS
            poses, _ = object_pose(spec.motion, object_category(spec.object), spec.object_size, times)
            paths.append(poses[:, [0, 2]])
        if len(paths) >= count:
            break
    return np.stack(paths[:count])


class PoolPolicy(abc.ABC):
    """Shared: the pool and hover height from the task, the palm's velocity from its own states."""

    name = "adv"
    action_horizon = 1
    privileged = False

    def reset(self, task: dict) -> None:
        text = str(task["text"])
        self._first = int(task["observe_frames"])
        self._horizon = int(task["horizon"])
        self._hover = hover_height(text)
        setting = setting_of(float(task.get("intercept_time_s", 1.0)))
        self._intercept = round(float(task.get("intercept_time_s", 1.0)) * FPS)
        self._pool = training_pool(object_from_text(text), setting, motion_named(text), self._horizon + 1)
        self._plan: np.ndarray | None = None

    def joints(self, t: int) -> np.ndarray:
        return REST_JOINTS

    def act(self, obs: dict) -> np.ndarray:
        t = int(obs["frame_index"]) - self._first
        palm = np.asarray(obs["palm_pose"], dtype=np.float64)[:3]
        if self._plan is None:
            self._plan = self.plan(palm)
        goal = self._plan[min(t + 1, len(self._plan) - 1)]
        return np.concatenate([goal, self.joints(t + 1)]).astype(np.float32)

    @abc.abstractmethod
    def plan(self, start: np.ndarray) -> np.ndarray:
        """(horizon + 1, 3) the palm at acting frames 0..horizon (row 0 = ``start``); each
        adversary plans its own."""


def follow(start: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """The palm positions the body reaches steering at ``targets`` (k, 3) one per frame, from rest."""
    out, palm, velocity = [], np.asarray(start, dtype=np.float64), np.zeros(3)
    for target in targets:
        new = limit_palm(palm, velocity, target)
        velocity, palm = new - palm, new
        out.append(palm)
    return np.array(out)


class JumpPolicy(PoolPolicy):
    """(a): each frame aims at one training path's next position (module docstring)."""

    name = "adv-jump"

    def plan(self, start: np.ndarray) -> np.ndarray:
        n = len(self._pool)
        order = np.random.default_rng(0).permutation(n)
        frames = np.arange(1, self._horizon + 1)
        xz = self._pool[order[frames % n], frames]
        targets = np.column_stack([xz[:, 0], np.full(len(xz), self._hover), xz[:, 1]])
        return np.vstack([start, follow(start, targets)])


def steer(palm: np.ndarray, velocity: np.ndarray, goal: np.ndarray, frames: int) -> np.ndarray:
    """(frames, 3) the body's positions steering to arrive at ``goal`` after ``frames`` frames."""
    out = []
    for k in range(frames, 0, -1):
        new = limit_palm(palm, velocity, palm + (goal - palm) / k)
        velocity, palm = new - palm, new
        out.append(palm)
    return np.array(out)


def run_lengths(close: np.ndarray) -> np.ndarray:
    """(n,) the longest run of True along axis 1 of ``close`` (n, k)."""
    best = np.zeros(len(close), dtype=np.int64)
    run = np.zeros(len(close), dtype=np.int64)
    for column in close.T:
        run = np.where(column, run + 1, 0)
        best = np.maximum(best, run)
    return best


class CoverPolicy(PoolPolicy):
    """(b): the greedy cover of the pool's paths (module docstring)."""

    name = "adv-cover"
    dwell = 1

    def covered(self, palm: np.ndarray) -> np.ndarray:
        """Which pool paths the planned palm (frames 0..len-1) covers."""
        k = len(palm)
        d = np.linalg.norm(self._pool[:, :k] - palm[None, :, [0, 2]], axis=2)
        return run_lengths(d <= LOC_TOLERANCE) >= self.dwell

    def plan(self, start: np.ndarray) -> np.ndarray:
        pool, horizon, k_dwell = self._pool, self._horizon, self.dwell
        palm = np.array([start])
        while len(palm) - 1 < horizon:
            t = len(palm) - 1
            velocity = palm[-1] - palm[-2] if len(palm) > 1 else np.zeros(3)
            done = self.covered(palm)
            open_ = ~done
            best: tuple[float, np.ndarray] | None = None
            for s in range(t + 1, min(t + LOOKAHEAD, horizon) + 1):
                end = min(s + k_dwell, horizon + 1)
                window = pool[:, s:end]  # candidate j followed over frames s..end-1
                near = np.all(np.linalg.norm(window[:, None] - window[None, open_], axis=3) <= LOC_TOLERANCE, axis=2)
                for j in np.argsort(-near.sum(axis=1))[:CANDIDATES]:
                    goal = np.array([window[j, 0, 0], self._hover, window[j, 0, 1]])
                    path = steer(palm[-1], velocity, goal, s - t)
                    if np.linalg.norm(path[-1, [0, 2]] - goal[[0, 2]]) > ARRIVE:
                        continue
                    rest = np.column_stack([window[j, 1:, 0], np.full(end - s - 1, self._hover), window[j, 1:, 1]])
                    if len(rest):
                        path = np.vstack([path, follow_from(path, palm[-1], rest)])
                    gain = float((self.covered(np.vstack([palm, path])) & open_).sum()) / len(path)
                    if gain > 0 and (best is None or gain > best[0]):
                        best = (gain, path)
            if best is None:  # nothing left to gain: hold still
                return np.vstack([palm, np.repeat(palm[-1:], horizon + 1 - len(palm), axis=0)])
            palm = np.vstack([palm, best[1]])[: horizon + 1]
        return palm


def follow_from(path: np.ndarray, before: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """:func:`follow` continued from the end of ``path`` (its velocity kept)."""
    prev = path[-2] if len(path) > 1 else before
    out, palm, velocity = [], path[-1], path[-1] - prev
    for target in targets:
        new = limit_palm(palm, velocity, target)
        velocity, palm = new - palm, new
        out.append(palm)
    return np.array(out)


class Dwell4Policy(CoverPolicy):
    """The cover counting a path only after 4 consecutive frames within 0.3."""

    name = "adv-cover-dwell4"
    dwell = 4


class ModePolicy(PoolPolicy):
    """Follows the pool's densest path and closes at its densest frame (module docstring)."""

    name = "adv-mode"
    #: Acting frames from the start of closing to a closed grasp (closing_joints' 80% point).
    CLOSING = 4

    def joints(self, t: int) -> np.ndarray:
        start = self._close - self.CLOSING
        return REST_JOINTS if t < start else closing_joints(FIST, t - start)

    def plan(self, start: np.ndarray) -> np.ndarray:
        best = (-1, 0, self.CLOSING + 1)  # (paths near, path, closing frame)
        for close in range(self.CLOSING + 1, self._horizon):
            around = self._pool[:, close - 1: close + 2]
            near = (np.linalg.norm(around[:, None] - around[None], axis=3) <= LOC_TOLERANCE).all(axis=2).sum(axis=1)
            if int(near.max()) > best[0]:
                best = (int(near.max()), int(np.argmax(near)), close)
        _, j, self._close = best
        xz = self._pool[j, 1:]
        targets = np.column_stack([xz[:, 0], np.full(len(xz), self._hover), xz[:, 1]])
        return np.vstack([start, follow(start, targets)])


ADVERSARIES = {cls.name: cls for cls in (JumpPolicy, CoverPolicy, Dwell4Policy, ModePolicy)}
ADVERSARY_CLASSES = {name: cls.__name__ for name, cls in ADVERSARIES.items()}


# --- the benchmark ------------------------------------------------------------------------

#: The built-in policies run beside the adversaries, and the ground truth (a build):
#: run name -> (policy, resolution; None: ``--resolution``). Predictive also at 224 px,
#: where it is measured (at 64 px its perception misses).
BUILTINS = {name: (name, None) for name in ("oracle", "predictive", "chase", "still", "blind-centre", "blind-sweep",
                                            "blind-first-seen", "blind-fitted")} | {"predictive-224": ("predictive", 224)}
GROUND_TRUTH = "ground-truth"
#: The built-ins that read no pixel (``blind-first-seen`` reads one frame, once).
PIXEL_FREE = ("still", "blind-centre", "blind-sweep", "blind-fitted")
#: S_loc (%) no pixel-free policy may exceed under a chosen rule (issue 38).
BLIND_BOUND = 10.0


def record(name: str, folder: str, episodes: int, resolution: int) -> float:
    """Run ``name`` (a built-in, an adversary, or the ground truth's build) into ``folder``; seconds."""
    policy, own = BUILTINS.get(name, (None, None))
    cli = [sys.executable, "-m", "pipeline.cli"]
    common = ["--slice", "test-1k", "--episodes", str(episodes), "--resolution", str(own or resolution),
              "--workers", "1", "--quiet", "--out", folder]
    if name == GROUND_TRUTH:
        command = cli + ["build"] + common
    elif policy is not None:
        command = cli + ["eval", "--policy", policy, "--overwrite"] + common
    else:
        command = cli + ["eval", "--policy", f"benchmarks.blind_adversaries:{ADVERSARY_CLASSES[name]}", "--in-process",
                         "--overwrite"] + common
    start = time.perf_counter()
    subprocess.run(command, check=True, cwd=ROOT)
    return round(time.perf_counter() - start, 1)


def run_path(runs: str, name: str) -> str:
    """Where run ``name`` is read from (a build writes its slice's folder inside OUT)."""
    folder = os.path.join(runs, name)
    return os.path.join(folder, "test-1k") if name == GROUND_TRUTH else folder


def scored(folder: str) -> dict:
    """``scoring eval FOLDER --json``'s S_loc, its interval and S_grasp_contact."""
    out = subprocess.run([sys.executable, "-m", "scoring.cli", "eval", folder, "--json"], check=True, cwd=ROOT,
                         capture_output=True, text=True).stdout
    report = json.loads(out)
    return {"S_loc": round(report["metrics"]["S_loc"], 1), "ci95": [round(v, 1) for v in report["intervals"]["S_loc"]],
            "S_grasp_contact": round(report["metrics"]["S_grasp_contact"], 1), "episodes": report["episodes"]}


def verdicts(table: dict[str, dict]) -> dict[str, dict]:
    """Per rule: whether the oracle and the ground truth stay at 100%, predictive's value,
    the highest pixel-free value and who reaches it, and whether it is <= BLIND_BOUND."""
    blind = [name for name in table if name in PIXEL_FREE or name.startswith("adv-")]
    out = {}
    for rule in next(iter(table.values())):
        worst = max(blind, key=lambda name: table[name][rule]["S_loc"])
        out[rule] = {"oracle_100": table["oracle"][rule]["S_loc"] == 100.0,
                     "ground_truth_100": table.get(GROUND_TRUTH, table["oracle"])[rule]["S_loc"] == 100.0,
                     "predictive_224": table["predictive-224"][rule]["S_loc"],
                     "predictive_64": table["predictive"][rule]["S_loc"], "chase": table["chase"][rule]["S_loc"],
                     "max_pixel_free": table[worst][rule]["S_loc"], "max_pixel_free_by": worst,
                     "pixel_free_within_bound": table[worst][rule]["S_loc"] <= BLIND_BOUND,
                     "blind_first_seen": table["blind-first-seen"][rule]["S_loc"]}
    return out


def single_frame_ceiling(episodes: int = 60, first: int = 10_000) -> dict:
    """What a pixel-free policy can reach under a one-frame rule (at-grasp, endpoint): its
    palm at the chosen frame is a function of the task, so it hits at most as often as the
    densest point of its pool at the densest frame. Measured on held-out *training* episodes
    ``first..`` (never test-1k): the pool's densest (frame, point) hits their object how often."""
    hits = []
    for k in range(episodes):
        setting, kind = SETTINGS[k % 3], MOTION_TYPES[(k // 3) % 3]
        spec = spec_for(f"{kind}-{setting}", first + k)
        h = horizon(spec)
        pool = training_pool(spec.object, setting, motion_named(spec.text), h + 1)
        times = (spec.observe_frames + np.arange(h + 1, dtype=np.float64)) / FPS
        own = object_pose(spec.motion, object_category(spec.object), spec.object_size, times)[0][:, [0, 2]]
        near = [(np.linalg.norm(pool[:, None, t] - pool[None, :, t], axis=2) <= LOC_TOLERANCE).sum(axis=1)
                for t in range(1, h + 1)]
        t = int(np.argmax([n.max() for n in near]))
        hits.append(bool(np.linalg.norm(own[t + 1] - pool[int(np.argmax(near[t])), t + 1]) <= LOC_TOLERANCE))
    lo, hi = wilson_interval(sum(hits), len(hits))
    return {"episodes": len(hits), "first_index": first, "S_loc": round(100 * sum(hits) / len(hits), 1),
            "ci95": [round(100 * lo, 1), round(100 * hi, 1)]}


def write_table(result: dict, json_path: str) -> None:
    """Every rule's S_loc per run as Markdown, beside the JSON (``.md``)."""
    table, names = result["table"], list(result["table"])
    lines = ["## S_loc under candidate rules", "",
             f"test-1k episodes 0-{result['episodes'] - 1}, {result['resolution']} px (predictive-224: 224 px), "
             f"commit {result['commit'][:7]}. Percent; 95% Wilson intervals in the JSON.", "",
             "| rule | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    lines += [f"| {rule} | " + " | ".join(f"{table[name][rule]['S_loc']:.1f}" for name in names) + " |"
              for rule in result["rules"]]
    with open(os.path.splitext(json_path)[0] + ".md", "w") as handle:
        handle.write("\n".join(lines) + "\n")


def main() -> None:
    import loc_rules  # beside this script (bench_setup keeps the benchmarks folder on sys.path)

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=60)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--runs", default=os.path.join(ROOT, "out", "blind_adversaries"), help="folder of the runs")
    parser.add_argument("--reuse", action="store_true", help="score runs already in --runs instead of recording them")
    parser.add_argument("--out", default=os.path.join(ROOT, "benchmarks", "results", "blind_adversaries.json"))
    args = parser.parse_args()
    load_start = [round(v, 2) for v in os.getloadavg()]
    names = [GROUND_TRUTH, *BUILTINS, *ADVERSARY_CLASSES]
    seconds, scores, table = {}, {}, {}
    for name in names:
        folder = run_path(args.runs, name)
        if not (args.reuse and os.path.exists(os.path.join(folder, "catalog.json"))):
            seconds[name] = record(name, os.path.join(args.runs, name), args.episodes, args.resolution)
        scores[name] = scored(folder)
        table[name] = loc_rules.score(loc_rules.episodes_of(load_run(folder)))
        if table[name]["today"]["S_loc"] != scores[name]["S_loc"]:
            raise SystemExit(f"{name}: the offline 'today' rule gives {table[name]['today']['S_loc']}, "
                             f"scoring eval {scores[name]['S_loc']}")
        print(f"{name}: S_loc {scores[name]['S_loc']} {scores[name]['ci95']}", flush=True)
    import bench_setup  # run as a script (above): the repository's own

    where = {k: v for k, v in bench_setup.provenance().items() if k != "load_average"}
    result = {"benchmark": "blind_adversaries", **where,
              "slice": "test-1k", "episodes": args.episodes, "resolution": args.resolution,
              "adversaries": {name: (globals()[cls].__doc__ or "").strip() for name, cls in ADVERSARY_CLASSES.items()},
              "pool": POOL, "rules": {name: text for name, (_, text) in loc_rules.RULES.items()},
              "scoring_eval": scores, "table": table, "verdicts": verdicts(table),
              "single_frame_ceiling": single_frame_ceiling(), "seconds": seconds,
              "reused_runs": [name for name in names if name not in seconds],
              "load_average_start": load_start, "load_average_end": [round(v, 2) for v in os.getloadavg()]}
    if result["dataset_version"] != DATASET_VERSION:
        raise SystemExit(f"dataset version {result['dataset_version']} != {DATASET_VERSION}")
    with open(args.out, "w") as handle:
        json.dump(result, handle, indent=1)
        handle.write("\n")
    write_table(result, args.out)

if __name__ == "__main__":
    main()
