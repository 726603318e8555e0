"""Write tiny run folders in the shard contract (catalog.json + Parquet shards) from
hand-made per-frame arrays, so scoring can be tested without the simulator."""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from catalog.store.hashing import sha256_file
from catalog.store.manifest import CodeInfo, Manifest, write_manifest
from catalog.store.records import FileRecord, ShardRecord, shard_paths
from catalog.tables.parquet_io import write_table
from generators.recipe import spec_for
from schemas.tables import (
    ARRAY_WIDTHS,
    EPISODES_SCHEMA,
    FRAMES_SCHEMA,
    ROLLOUT_EPISODES_SCHEMA,
    STATE_COLUMNS,
)
from schemas.versions import DATASET_VERSION

CLOSED = np.ones(15, dtype=np.float32)


@dataclass
class Ep:
    """One episode: per-frame phases, palm and object XYZ, joint angles and fingertip distances."""

    phases: list[str]
    palm: list[list[float]]
    obj: list[list[float]] | None = None
    joints: np.ndarray | None = None
    tips: list[float] | None = None
    grasp: np.ndarray = field(default_factory=lambda: CLOSED.copy())
    motion_type: str = "linear"
    intercept_setting: str = "fast"
    object: str = "tennis_ball"
    status: str = "ok"


def _fixed(values: np.ndarray, width: int) -> pa.FixedSizeListArray:
    flat = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float32()), width)


def frames_table(first_index: int, episodes: list[Ep]) -> pa.Table:
    cols: dict[str, list] = {name: [] for name in FRAMES_SCHEMA.names}
    arrays: dict[str, list[np.ndarray]] = {name: [] for name in (*STATE_COLUMNS, "action")}
    for offset, ep in enumerate(episodes):
        k = len(ep.phases)
        cols["episode_index"] += [first_index + offset] * k
        cols["frame_index"] += list(range(k))
        cols["timestamp"] += [i / 20 for i in range(k)]
        cols["phase"] += ep.phases
        cols["image"] += [b"\xff\xd8 not really a jpeg"] * k
        cols["fingertip_distance"] += list(ep.tips if ep.tips is not None else [1.0] * k)
        palm = np.zeros((k, 6), np.float32)
        palm[:, :3] = np.asarray(ep.palm, dtype=np.float32).reshape(k, 3)
        obj = np.zeros((k, 7), np.float32)
        obj[:, 6] = 1.0
        if ep.obj is not None:
            obj[:, :3] = np.asarray(ep.obj, dtype=np.float32).reshape(k, 3)
        joints = np.zeros((k, 15), np.float32) if ep.joints is None else np.asarray(ep.joints, np.float32)
        for name in arrays:
            arrays[name].append(np.zeros((k, ARRAY_WIDTHS[name]), np.float32))
        arrays["palm_pose"][-1] = palm
        arrays["object_pose"][-1] = obj
        arrays["joint_angles"][-1] = joints
    columns = []
    for f in FRAMES_SCHEMA:
        if f.name in arrays:
            columns.append(_fixed(np.concatenate(arrays[f.name]), ARRAY_WIDTHS[f.name]))
        else:
            columns.append(pa.array(cols[f.name], type=f.type))
    return pa.Table.from_arrays(columns, schema=FRAMES_SCHEMA)


@functools.cache
def _spec_json(object_name: str) -> str:
    """A real spec (test-1k's episode 0) with the episode's object at size 1 and the right
    hand, which the hold test (S_hold) reads."""
    return dataclasses.replace(spec_for("test-1k", 0), object=object_name, object_size=1.0, hand="right").to_json()


def episodes_table(first_index: int, episodes: list[Ep], policy: str | None) -> pa.Table:
    schema = EPISODES_SCHEMA if policy is None else ROLLOUT_EPISODES_SCHEMA
    rows = []
    for offset, ep in enumerate(episodes):
        index = first_index + offset
        rows.append({
            "episode_index": index, "episode_id": f"test:{index:06d}", "slice": "test", "motion_type": ep.motion_type,
            "tokens": "[]", "object": ep.object, "object_size": 1.0, "rolling": False, "hand": "right",
            "rollout_format": "observe-before-act", "intercept_setting": ep.intercept_setting,
            "intercept_time_s": 0.5, "observe_frames": ep.phases.count("observe"), "intercept_frame": 0,
            "num_frames": len(ep.phases), "grasp_angles": np.asarray(ep.grasp, np.float32), "seed": 1,
            "spec_hash": "0" * 64, "text": "", "spec": _spec_json(ep.object),
            "policy": policy, "privileged": False, "status": ep.status, "error": "boom" if ep.status == "error" else "",
        })
    columns = []
    for f in schema:
        values = [row[f.name] for row in rows]
        if pa.types.is_fixed_size_list(f.type):
            columns.append(_fixed(np.stack(values), f.type.list_size))
        else:
            columns.append(pa.array(values, type=f.type))
    return pa.Table.from_arrays(columns, schema=schema)


def write_run(
    folder: Path,
    episodes: list[Ep],
    policy: str | None = "oracle",
    shard_size: int = 2,
    drop_frame_column: str | None = None,
) -> Path:
    """Write ``episodes`` as a run (``policy`` set) or a built slice (``policy=None``)."""
    folder.mkdir(parents=True, exist_ok=True)
    shards = []
    for first in range(0, len(episodes), shard_size):
        chunk = episodes[first:first + shard_size]
        end = first + len(chunk)
        paths = shard_paths(first, end)
        for kind in ("frames", "episodes", "mcap"):
            (folder / kind).mkdir(exist_ok=True)
        frames = frames_table(first, chunk)
        if drop_frame_column:
            pq.write_table(frames.drop_columns([drop_frame_column]), folder / paths["frames"])
        else:
            write_table(folder / paths["frames"], frames, "frames")
        kind = "episodes" if policy is None else "rollout_episodes"
        write_table(folder / paths["episodes"], episodes_table(first, chunk, policy), kind)
        (folder / paths["mcap"]).write_bytes(b"")
        files = {
            kind: FileRecord(rel, sha256_file(folder / rel), (folder / rel).stat().st_size)
            for kind, rel in paths.items()
        }
        shards.append(ShardRecord((first, end), frames.num_rows, files))
    settings = {"fps": 20, "resolution": 224, "image_format": "jpeg", "jpeg_quality": 90, "dataset_version": DATASET_VERSION}
    extra = {} if policy is None else {"policy": policy}
    manifest = Manifest.create("test", 1, settings, shards, code=CodeInfo("0.1.0", None), extra=extra)
    write_manifest(folder, manifest)
    return folder


def png_size(path) -> tuple[int, int]:
    """(width, height) of a PNG file, from its header."""
    import struct

    header = path.read_bytes()[:24]
    assert header[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", header[16:24])
