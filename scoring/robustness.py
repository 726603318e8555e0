"""Robustness across repeats (paper A.5): the same episodes evaluated K times under seeded,
visually negligible perturbations (``pipeline eval --repeats K --perturb ...``).

Per episode, over its K repeats:

* **consistency**: ``all`` repeats succeed, ``none`` does, or ``mixed``; for localization
  (S_loc's event) and for the contact grasp (S_grasp_contact's): the rates of
  :mod:`scoring.registry` that name a ``consistency``;
* **spread**: the standard deviation across repeats of each per-episode measure (the
  registry's means: E_loc, E_gra, Q_smooth, Q_line, R_time), averaged over episodes; and
  the standard deviation of each of those success rates across the K runs;
* **action divergence**: the mean distance between the palm targets two repeats issued at
  the same acting frame (over the frames both recorded), in units of the 0.3-unit
  localization tolerance, averaged over repeat pairs and episodes: 0 means the
  perturbation never changed an action, 1 means actions differ by a whole tolerance.

Reads only recorded shards, through the checked reader; ``repeats.json`` must name each
repeat's manifest hash.
"""

from __future__ import annotations

import itertools
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from catalog.store.storage import as_location
from catalog.tables.parquet_io import column_to_numpy
from catalog.tables.reader import open_folder
from schemas.errors import ShardError
from schemas.scene import LOC_TOLERANCE
from scoring.hold import run_metrics
from scoring.io import RunData, load_run
from scoring.metrics import DEFAULT_READING, EpisodeMetrics, failed, reading_named
from scoring.registry import registered

REPEATS_FILE = "repeats.json"


def is_repeats_folder(folder: str | os.PathLike[str]) -> bool:
    return (as_location(folder) / REPEATS_FILE).is_file()


@dataclass(frozen=True)
class RepeatSet:
    """The K runs of one robustness experiment, their index and each run's palm targets."""

    folder: Path
    index: dict[str, Any]
    runs: tuple[RunData, ...]
    targets: tuple[dict[int, np.ndarray], ...]  # per run: episode index -> (acting frames, 3)


def _targets(folder: Path) -> dict[int, np.ndarray]:
    out: dict[int, np.ndarray] = {}
    for shard in open_folder(folder):
        frames = shard.frames(["phase", "action"])
        episode = column_to_numpy(frames.column("episode_index"))
        acting = np.asarray(frames.column("phase").to_pylist()) != "observe"
        action = column_to_numpy(frames.column("action"))[:, :3].astype(np.float64)
        for index in np.unique(episode):
            out[int(index)] = action[(episode == index) & acting]
    return out


def load_repeats(folder: str | os.PathLike[str]) -> RepeatSet:
    """Read ``repeats.json`` and every repeat it names (each manifest's hash checked)."""
    root = as_location(folder)
    path = root / REPEATS_FILE
    try:
        index = json.loads(path.read_text())
        entries = index["runs"]
        paths = [e["path"] for e in entries]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ShardError(f"{path}: not a readable repeats index ({exc})") from None
    runs, targets = [], []
    for entry, rel in zip(entries, paths):
        if not isinstance(rel, str) or "/" in rel or "\\" in rel or rel in ("", ".", ".."):
            raise ShardError(f"{path}: a repeat's path must be a folder name, got {rel!r}")
        run = load_run(root / rel)
        manifest = json.loads((root / rel / "catalog.json").read_text())
        if manifest.get("hash") != entry.get("hash"):
            raise ShardError(f"{root / rel}: its manifest hash does not match {path} (edited or rerun?)")
        runs.append(run)
        targets.append(_targets(root / rel))
    if len(runs) < 2:
        raise ShardError(f"{path}: a robustness experiment needs at least 2 repeats, found {len(runs)}")
    first = runs[0].episode_index.tolist()
    for rel, run in zip(paths[1:], runs[1:]):
        if run.episode_index.tolist() != first:
            raise ShardError(f"{root / rel}: holds other episodes than {paths[0]}")
    return RepeatSet(root, index, tuple(runs), tuple(targets))


def _per_episode(run: RunData, reading: str) -> EpisodeMetrics:
    return run_metrics(run, reading_named(reading))


def _consistency(success: np.ndarray) -> dict[str, int]:
    """success (K, n) -> counts of episodes where all, none or some repeats succeed."""
    every, any_ = success.all(axis=0), success.any(axis=0)
    return {"all": int(every.sum()), "none": int((~any_).sum()), "mixed": int((any_ & ~every).sum())}


def _divergence(targets: tuple[dict[int, np.ndarray], ...], episodes: list[int]) -> float | None:
    values = []
    for index in episodes:
        pairs = []
        for a, b in itertools.combinations(range(len(targets)), 2):
            x, y = targets[a].get(index), targets[b].get(index)
            if x is None or y is None:
                continue
            m = min(len(x), len(y))
            if m:
                pairs.append(float(np.linalg.norm(x[:m] - y[:m], axis=1).mean()) / LOC_TOLERANCE)
        if pairs:
            values.append(float(np.mean(pairs)))
    return float(np.mean(values)) if values else None


def _summary(repeats: RepeatSet, per: list[EpisodeMetrics], select: np.ndarray, contact_fails: bool) -> dict[str, Any]:
    ok = [~failed(r.error, r.min_clearance, contact_fails) for r in repeats.runs]  # as each repeat's summary
    tracked = [m for m in registered() if m.is_rate and m.consistency]
    success = {m.name: np.stack([m.success(p, o) for p, o in zip(per, ok)])[:, select] for m in tracked}
    spread = {}
    for metric in registered():
        if metric.is_rate:
            continue
        # each repeat's own value, statuses not applied (an error's frames still measure)
        values = np.stack([metric.per_episode(p, np.ones(len(p), dtype=bool)) for p in per])[:, select].astype(np.float64)
        counted = np.isfinite(values).sum(axis=0) >= 2
        stds = np.array([np.std(column[np.isfinite(column)]) for column in values.T[counted]])
        spread[metric.name] = float(stds.mean()) if len(stds) else None
    n = int(select.sum())
    rates = {name: [100.0 * float(row.mean()) for row in rows] if n else [] for name, rows in success.items()}
    episodes = [int(i) for i in repeats.runs[0].episode_index[select]]
    return {
        "episodes": n,
        "consistency": {m.consistency: _consistency(success[m.name]) for m in tracked},
        "spread": spread,
        "rate_std": {k: float(np.std(v)) if v else None for k, v in rates.items()},
        "rates": rates,
        "action_divergence": _divergence(repeats.targets, episodes),
    }


def robustness(repeats: RepeatSet, reading: str = DEFAULT_READING, contact_fails: bool = True) -> dict[str, Any]:
    """The robustness report (module docstring): overall and by motion type, under the
    metric ``reading`` (:data:`scoring.metrics.READINGS`); with ``contact_fails`` an obstacle
    contact fails an episode, as in ``scoring eval --obstacle-contact fail``."""
    per = [_per_episode(run, reading) for run in repeats.runs]
    n = repeats.runs[0].episodes
    out = {
        "run": repeats.folder.name,
        "policy": repeats.index.get("policy"),
        "slice": repeats.index.get("slice"),
        "repeats": len(repeats.runs),
        "protocol": repeats.index.get("protocol"),
        **_summary(repeats, per, np.ones(n, dtype=bool), contact_fails),
    }
    motions = repeats.runs[0].motion_type
    out["by_motion"] = {m: _summary(repeats, per, motions == m, contact_fails) for m in sorted(set(motions.tolist()))}
    return out


def robustness_lines(report: dict[str, Any]) -> list[str]:
    """The terminal view of :func:`robustness`."""
    protocol = report.get("protocol") or {}
    head = (f"Robustness of {report['policy']} on {report['slice']}: {report['episodes']} episodes x "
            f"{report['repeats']} repeats, perturb {protocol.get('perturb')}:{protocol.get('perturb_strength')}")
    lines = [head, f"{'group':12s} {'loc all/none/mixed':>20s} {'contact all/none/mixed':>24s} "
             f"{'S_loc sd':>9s} {'E_loc sd':>9s} {'divergence':>11s}"]
    rows = [("all", report)] + list(report["by_motion"].items())
    for name, r in rows:
        loc, con = r["consistency"]["localization"], r["consistency"]["grasp_contact"]
        e = r["spread"]["E_loc"]
        d = r["action_divergence"]
        s = r["rate_std"]["S_loc"]
        lines.append(
            f"{name:12s} {loc['all']:>6d}/{loc['none']:>4d}/{loc['mixed']:>4d}      "
            f"{con['all']:>8d}/{con['none']:>4d}/{con['mixed']:>4d}      "
            f"{'-' if s is None else f'{s:.2f}':>9s} {'-' if e is None else f'{e:.3f}':>9s} "
            f"{'-' if d is None else f'{d:.3f}':>11s}"
        )
    lines.append("consistency: episodes whose repeats all / none / some succeed; sd: standard deviation across "
                 "repeats; divergence: mean palm-target distance between repeats, in localization tolerances (0.3)")
    return lines
