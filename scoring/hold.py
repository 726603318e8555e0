"""S_hold's per-episode fact: the hold test (:mod:`generators.hold`) run from the frame each
episode's grasp first closed, on what the run recorded.

The test needs pybullet dynamics per closed episode (about 50-80 ms of CPU each), so it
runs once per scored run, for the episodes that closed (S_gra) and are not in error;
an episode that never closed has nothing to hold. The hand and the grasp are those of the
folder's dataset version (:func:`generators.grasp.design_of`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from generators.grasp import GraspDesign, design_of
from generators.hold_episode import hold_at
from schemas.errors import ShardError
from schemas.versions import FPS
from scoring.io import RunData
from scoring.metrics import EpisodeMetrics, Reading, episode_metrics


def hold_frames(data: RunData, t_gra: np.ndarray, design: GraspDesign | None = None) -> np.ndarray:
    """(n,) for each episode of ``data``, ``t_gra`` (its first closed acting frame) if the
    object stayed in the hand through the hold test from there, else -1. ``design``: the
    hand and grasp (default: the folder's dataset version's)."""
    n = data.episodes
    out = np.full(n, -1, dtype=np.int64)
    closed = np.flatnonzero((np.asarray(t_gra) >= 0) & ~data.error)
    if not len(closed):
        return out
    if data.specs is None or data.palm_rotation is None or data.palm_before is None:
        raise ShardError(f"{data.name}: the hold test needs the episodes' specs and palm poses, which were not read")
    chosen = design_of(data.dataset_version) if design is None else design
    for i in closed:
        row = int(data.offsets[i] + t_gra[i])
        spec = data.specs[i]
        before = data.palm_xyz[row - 1] if t_gra[i] > 0 else data.palm_before[i]
        velocity = (data.palm_xyz[row].astype(np.float64) - before) * float(FPS)
        palm = np.concatenate([data.palm_xyz[row], data.palm_rotation[row]]).astype(np.float64)
        frame = spec.observe_frames + int(t_gra[i])
        if hold_at(spec, frame, palm, velocity, data.joint_angles[row], chosen).held:
            out[i] = t_gra[i]
    return out


def run_metrics(data: RunData, reading: Reading, design: GraspDesign | None = None) -> EpisodeMetrics:
    """:func:`scoring.metrics.episode_metrics` of ``data`` with its hold test (``t_hold``)."""
    per = episode_metrics(data.offsets, data.palm_xyz, data.object_xyz, data.joint_angles, data.fingertip_distance,
                          data.grasp_angles, data.acting_budget, data.hover_offset, data.top_offset, reading)
    return dataclasses.replace(per, t_hold=hold_frames(data, per.t_gra, design))
