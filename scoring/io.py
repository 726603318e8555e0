"""Load a run (evaluated rollouts) or a built slice into the arrays the metrics need.

Only the columns the metrics use are read, never ``image``: that keeps scoring a
thousand rollouts to a fraction of a second. Anything that is not a readable set
of shards raises :class:`ShardError` naming the folder or file.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from catalog.tables.parquet_io import column_to_numpy
from catalog.tables.reader import ShardReader, open_folder
from schemas.errors import ShardError, SpecError
from schemas.events import PROJECTILE_MARK, acting, acting_budget, hover_offset, spec_hover_offset
from schemas.frames import EpisodeFrames
from schemas.names import shorten
from schemas.objects import object_category
from schemas.scene import PHASES
from schemas.spec import EpisodeSpec
from schemas.tables import OBSTACLE_CLEARANCE
from schemas.versions import FPS

FRAME_COLUMNS = ("episode_index", "frame_index", "phase", "palm_pose", "object_pose", "joint_angles", "fingertip_distance")
EPISODE_COLUMNS = (
    "episode_index", "episode_id", "motion_type", "intercept_setting", "object", "hand", "rollout_format",
    "grasp_angles", "num_frames", "observe_frames", "object_size", "tokens", "spec",
)
ROLLOUT_COLUMNS = ("policy", "privileged", "status", "error")
#: Phases in which the hand acts; every other frame is observation only.
OBSERVE = "observe"


@dataclass(frozen=True)
class RunData:
    """One run's episodes (``n``, sorted by index) and their acting frames (``m``).

    ``offsets`` (n + 1) delimit each episode's acting frames, in frame order;
    ``policy`` is None for a built (ground-truth) slice, whose episodes are all ok.
    ``acting_budget`` (n,) is R_time's N (:func:`schemas.events.acting_budget`);
    ``error_message`` (n,) the recorded reason of each failed episode (None otherwise);
    ``privileged``: the policy read the ground-truth spec (an upper bound, not a fair entry).
    """

    name: str
    slice: str
    policy: str | None
    episode_index: np.ndarray
    motion_type: np.ndarray
    intercept_setting: np.ndarray
    object: np.ndarray
    error: np.ndarray
    grasp_angles: np.ndarray
    offsets: np.ndarray
    acting_budget: np.ndarray
    palm_xyz: np.ndarray
    object_xyz: np.ndarray
    joint_angles: np.ndarray
    fingertip_distance: np.ndarray
    error_message: np.ndarray
    episode_id: np.ndarray
    hand: np.ndarray
    rollout_format: np.ndarray
    privileged: bool = False
    #: (n,) the hover point's height above the object's centre for a flying object,
    #: NaN for one on the table (:func:`schemas.events.hover_offset`).
    hover_offset: np.ndarray | None = None
    #: (n,) the height of each object's top above its centre (its half height), for the
    #: ``top`` localization rule (:func:`top_offsets`).
    top_offset: np.ndarray | None = None
    #: (n,) the hand's smallest obstacle clearance over each episode's acting frames (+inf
    #: where the episode has no obstacle); None when the run records no clearance.
    min_clearance: np.ndarray | None = None
    #: The run's evaluation protocol (``settings.protocol``: latency, perturbation, repeat,
    #: disturbances, real time), None for a plain run or a built slice.
    protocol: dict | None = None
    #: (n,) when each episode's motion was disturbed (s; the start of its last base token)
    #: under ``pipeline eval --disturb``; None otherwise.
    disturbance_time_s: np.ndarray | None = None
    #: (n,) each episode's spec (as recorded: a disturbed run's disturbed motion), for the
    #: hold test (:mod:`scoring.hold`); None where not read.
    specs: tuple[EpisodeSpec, ...] | None = None
    #: (m, 3) the palm's orientation at the acting frames, and (n, 3) its position at the
    #: frame before each episode's first acting frame (the hold test's palm velocity).
    palm_rotation: np.ndarray | None = None
    palm_before: np.ndarray | None = None
    #: The folder's ``settings.dataset_version`` (which hand and grasp it has), None if unknown.
    dataset_version: str | None = None

    @property
    def episodes(self) -> int:
        return len(self.episode_index)

    @property
    def ground_truth(self) -> bool:
        return self.policy is None


def _strings(column: pa.ChunkedArray) -> np.ndarray:
    return np.asarray(column.to_pylist(), dtype=object)


def load_run(folder: str | os.PathLike[str]) -> RunData:
    """Read a run or slice folder (``catalog.json`` + shards) for scoring, through
    :func:`catalog.tables.reader.open_folder` (the checks every reader makes)."""
    reader = open_folder(folder)
    if not reader.shards or reader.manifest.episodes == 0:
        raise ShardError(f"{folder}: the run is empty (no episodes)")
    check_complete(folder, [shard.record.episodes for shard in reader], reader.manifest.episodes)
    return read_shards(reader.root, list(reader), reader.manifest.slice, reader.manifest.settings, reader.rollout)


def read_shards(root: Path, shards: Sequence[ShardReader], slice_name: str, settings: Mapping[str, Any],
                rollout: bool) -> RunData:
    """What :func:`load_run` reads, of ``shards`` (in order) of the folder ``root`` whose
    manifest names ``slice_name`` and ``settings``: a task scores the shard it just wrote."""
    protocol = settings.get("protocol")
    disturb = bool(protocol and protocol.get("disturb"))
    columns = EPISODE_COLUMNS + (ROLLOUT_COLUMNS if rollout else ())
    frame_columns = FRAME_COLUMNS + ((OBSTACLE_CLEARANCE,) if settings.get(OBSTACLE_CLEARANCE) else ())
    episode_tables, frame_tables = [], []
    for shard in shards:
        episodes = shard.episodes(columns)
        episode_tables.append(episodes)
        frame_tables.append(shard.frames(frame_columns, episodes))
    episodes = pa.concat_tables(episode_tables)
    data = _assemble(root, slice_name, episodes, pa.concat_tables(frame_tables), rollout)
    data = dataclasses.replace(data, dataset_version=settings.get("dataset_version"))
    if protocol is None:
        return data
    disturbed = None
    if disturb:
        fps = int(settings.get("fps", FPS))
        disturbed = np.array([disturbance_time(text, fps) for text in episodes.column("spec").to_pylist()],
                             dtype=np.float64)
    return dataclasses.replace(data, protocol=dict(protocol), disturbance_time_s=disturbed)


def check_complete(folder: str | os.PathLike[str], ranges: Sequence[tuple[int, int]], episodes: int) -> None:
    """ShardError naming what is missing unless the shards' episode ranges ``[first, end)``
    hold episodes 0..``episodes``-1 each exactly once: a run or slice always starts at
    episode 0, so a removed shard (its manifest re-hashed to match) is found, not scored
    as if the run were whole."""
    expected = 0
    for first, end in sorted(ranges):
        if first > expected:
            raise ShardError(f"{folder}: episodes {_span(expected, first)} are missing (no shard holds them; "
                             "a run holds episodes 0 to N-1)")
        if first < expected:
            raise ShardError(f"{folder}: episodes {_span(first, min(end, expected))} are listed twice")
        expected = end
    if expected != episodes:
        raise ShardError(f"{folder}: the shards hold episodes {_span(0, expected)}, catalog.json says {episodes}")


def _span(first: int, end: int) -> str:
    return f"{first}" if end - first == 1 else f"{first}-{end - 1}"


def disturbance_time(spec_json: str, fps: int) -> float:
    """When a disturbed episode's motion changed (s; its spec's ``disturbance.frame`` /
    fps), NaN for an episode left undisturbed."""
    disturbance = json.loads(spec_json).get("disturbance")
    return float("nan") if disturbance is None else disturbance["frame"] / fps


def _assemble(root: Path, slice_name: str, episodes: pa.Table, frames: pa.Table, rollout: bool) -> RunData:
    where = str(root)
    index = episodes.column("episode_index").to_numpy()

    if rollout:
        status = _strings(episodes.column("status"))
        unknown = sorted(set(status) - {"ok", "error"})
        if unknown:
            raise ShardError(f"{where}: unknown episode status {unknown[0]!r} (expected 'ok' or 'error')")
        error = status == "error"
        error_message = _strings(episodes.column("error"))
        error_message[~error] = None
        policy = ", ".join(sorted(set(episodes.column("policy").to_pylist())))
        privileged = any(episodes.column("privileged").to_pylist())
    else:
        error = np.zeros(len(index), dtype=bool)
        error_message = np.full(len(index), None, dtype=object)
        policy = None
        privileged = False

    phases = set(pc.unique(frames.column("phase")).to_pylist())
    if not phases <= set(PHASES):
        raise ShardError(f"{where}: unknown phase {sorted(phases - set(PHASES))[0]!r} (expected one of {list(PHASES)})")
    frame_episode = frames.column("episode_index").to_numpy()
    acting = pc.not_equal(frames.column("phase"), OBSERVE).to_numpy(zero_copy_only=False)
    row = np.searchsorted(index, frame_episode)
    pick = np.flatnonzero(acting)
    counts = np.bincount(row[acting], minlength=len(index))
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    def frame_array(name: str) -> np.ndarray:
        return check_finite(name, column_to_numpy(frames.column(name))[pick])

    def check_finite(name: str, values: np.ndarray) -> np.ndarray:
        bad = ~np.isfinite(values.reshape(len(values), -1)).all(axis=1)
        if bad.any():
            at = np.flatnonzero(bad)[0]
            episode = index[np.searchsorted(offsets, at, side="right") - 1]
            raise ShardError(f"{where}: non-finite {name} in an acting frame of episode {episode}")
        return values

    min_clearance = None
    if OBSTACLE_CLEARANCE in frames.column_names:
        values = column_to_numpy(frames.column(OBSTACLE_CLEARANCE))[pick].astype(np.float64)
        if np.isnan(values).any():
            at = int(np.flatnonzero(np.isnan(values))[0])
            episode = index[np.searchsorted(offsets, at, side="right") - 1]
            raise ShardError(f"{where}: NaN obstacle_clearance in an acting frame of episode {episode}")
        min_clearance = episode_minimum(values, offsets)

    every_palm = column_to_numpy(frames.column("palm_pose"))
    palm = check_finite("palm_pose", every_palm[pick])
    first_acting = pick[offsets[:-1][counts > 0]]
    before = np.full((len(index), 3), np.nan)
    before[counts > 0] = every_palm[np.maximum(first_acting - 1, 0), :3]
    grasp_angles = column_to_numpy(episodes.column("grasp_angles"))
    if not np.isfinite(grasp_angles).all():
        episode = index[np.flatnonzero(~np.isfinite(grasp_angles).all(axis=1))[0]]
        raise ShardError(f"{where}: non-finite grasp_angles in episode {episode}")

    return RunData(
        name=root.resolve().name,
        slice=slice_name,
        policy=policy,
        episode_index=index,
        motion_type=_strings(episodes.column("motion_type")),
        intercept_setting=_strings(episodes.column("intercept_setting")),
        object=_strings(episodes.column("object")),
        error=error,
        grasp_angles=grasp_angles,
        offsets=offsets,
        acting_budget=np.asarray(
            acting_budget(
                episodes.column("num_frames").to_numpy().astype(np.int64),
                episodes.column("observe_frames").to_numpy().astype(np.int64),
                rollout,
                counts.astype(np.int64),
            )
        ),
        palm_xyz=palm[:, :3],
        palm_rotation=palm[:, 3:6],
        palm_before=before,
        specs=tuple(EpisodeSpec.from_json(text) for text in episodes.column("spec").to_pylist()),
        object_xyz=frame_array("object_pose")[:, :3],
        joint_angles=frame_array("joint_angles"),
        fingertip_distance=frame_array("fingertip_distance"),
        error_message=error_message,
        episode_id=_strings(episodes.column("episode_id")),
        hand=_strings(episodes.column("hand")),
        rollout_format=_strings(episodes.column("rollout_format")),
        privileged=privileged,
        min_clearance=min_clearance,
        top_offset=top_offsets(episodes.column("object").to_pylist(), episodes.column("object_size").to_pylist()),
        hover_offset=np.array(
            [
                hover_offset(name, size, PROJECTILE_MARK in tokens)
                for name, size, tokens in zip(
                    episodes.column("object").to_pylist(),
                    episodes.column("object_size").to_pylist(),
                    episodes.column("tokens").to_pylist(),
                )
            ],
            dtype=np.float64,
        ),
    )


def _items(argument: str, value: object, kind: type) -> list:
    """``value`` as a list of ``kind``, else a SpecError naming ``argument``."""
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise SpecError(f"{argument} must be a list of {kind.__name__}, got {shorten(repr(value))}")
    items = list(value)
    for k, item in enumerate(items):
        if not isinstance(item, kind):
            article = "an" if kind.__name__[0] in "AEIOU" else "a"
            raise SpecError(f"{argument}[{k}] must be {article} {kind.__name__}, got {shorten(repr(item))}")
    return items


def _check_recordings(name: object, slice_name: object, specs: object, recordings: object, policy: object,
                      errors: object) -> None:
    """SpecError naming the first argument of :func:`from_recordings` that is not what it needs."""
    for argument, value in (("name", name), ("slice_name", slice_name)):
        if not isinstance(value, str):
            raise SpecError(f"{argument} must be a str, got {shorten(repr(value))}")
    if policy is not None and not isinstance(policy, str):
        raise SpecError(f"policy must be a str or None, got {shorten(repr(policy))}")
    n = len(_items("specs", specs, EpisodeSpec))
    if n == 0:
        raise SpecError("specs must hold at least one EpisodeSpec, got none")
    count = len(_items("recordings", recordings, EpisodeFrames))
    if count != n:
        raise SpecError(f"recordings must hold one EpisodeFrames per spec ({n}), got {count}")
    if errors is not None:
        if isinstance(errors, (str, bytes)) or not isinstance(errors, Sequence):
            raise SpecError(f"errors must be a list of str or None, got {shorten(repr(errors))}")
        if len(errors) != n:
            raise SpecError(f"errors must have one entry per spec ({n}), got {len(errors)}")
        for k, item in enumerate(errors):
            if item is not None and not isinstance(item, str):
                raise SpecError(f"errors[{k}] must be a str or None, got {shorten(repr(item))}")


def from_recordings(
    name: str,
    slice_name: str,
    specs: Sequence[EpisodeSpec],
    recordings: Sequence[EpisodeFrames],
    policy: str | None = None,
    errors: Sequence[str | None] | None = None,
) -> RunData:
    """A :class:`RunData` from episodes held in memory (a benchmark's, a notebook's),
    scored exactly as their shards would be: ``policy`` None means ground truth; else
    they are rollouts (R_time's N is the acting horizon) and ``errors`` holds each
    episode's failure reason or None. Wrong types or counts: a SpecError naming the argument."""
    _check_recordings(name, slice_name, specs, recordings, policy, errors)
    rollout = policy is not None
    messages = np.array(list(errors) if errors is not None else [None] * len(specs), dtype=object)
    picks = [acting(frames.phase) for frames in recordings]
    counts = np.array([int(p.sum()) for p in picks], dtype=np.int64)

    def stacked(field: str, width: slice | None = None) -> np.ndarray:
        parts = [getattr(f, field)[p] for f, p in zip(recordings, picks)]
        values = np.concatenate(parts)
        return values if width is None else values[:, width]

    return RunData(
        name=name,
        slice=slice_name,
        policy=policy,
        episode_index=np.array([s.episode_index for s in specs], dtype=np.int64),
        motion_type=np.array([s.motion_type for s in specs], dtype=object),
        intercept_setting=np.array([s.intercept_setting for s in specs], dtype=object),
        object=np.array([s.object for s in specs], dtype=object),
        error=np.array([m is not None for m in messages], dtype=bool) if rollout else np.zeros(len(specs), bool),
        grasp_angles=np.stack([f.grasp_angles for f in recordings]),
        offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        acting_budget=np.asarray(
            acting_budget(
                np.array([s.num_frames for s in specs], dtype=np.int64),
                np.array([s.observe_frames for s in specs], dtype=np.int64),
                rollout,
                counts,
            )
        ),
        palm_xyz=stacked("palm_pose", slice(0, 3)),
        palm_rotation=stacked("palm_pose", slice(3, 6)),
        palm_before=np.array([f.palm_pose[max(int(np.argmax(p)) - 1, 0), :3] if p.any() else np.full(3, np.nan)
                              for f, p in zip(recordings, picks)]).reshape(len(specs), 3),
        specs=tuple(specs),
        object_xyz=stacked("object_pose", slice(0, 3)),
        joint_angles=stacked("joint_angles"),
        fingertip_distance=stacked("fingertip_distance"),
        error_message=messages if rollout else np.full(len(specs), None, dtype=object),
        episode_id=np.array([s.episode_id for s in specs], dtype=object),
        hand=np.array([s.hand for s in specs], dtype=object),
        rollout_format=np.array([s.rollout_format for s in specs], dtype=object),
        hover_offset=np.array([spec_hover_offset(s) for s in specs], dtype=np.float64),
        top_offset=top_offsets([s.object for s in specs], [s.object_size for s in specs]),
        min_clearance=_recorded_clearance(recordings, picks, counts) if any(s.obstacles for s in specs) else None,
    )


def top_offsets(objects: Sequence[str], sizes: Sequence[float]) -> np.ndarray:
    """(n,) each object's top above its centre: its category's half height at its size."""
    return np.array([object_category(o).half_height(float(z)) for o, z in zip(objects, sizes)], dtype=np.float64)


def episode_minimum(values: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(n,) minimum of each episode's run of ``values`` (delimited by ``offsets``); +inf
    for an episode without rows."""
    out = np.full(len(offsets) - 1, np.inf)
    owner = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    np.minimum.at(out, owner, values)
    return out


def _recorded_clearance(recordings: Sequence[EpisodeFrames], picks: list[np.ndarray], counts: np.ndarray) -> np.ndarray:
    parts = [
        np.full(int(p.sum()), np.inf) if f.obstacle_clearance is None else f.obstacle_clearance[p].astype(np.float64)
        for f, p in zip(recordings, picks)
    ]
    values = np.concatenate(parts) if parts else np.zeros(0)
    return episode_minimum(values, np.concatenate([[0], np.cumsum(counts)]).astype(np.int64))
