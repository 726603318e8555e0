"""The metadata of a LeRobot export, assembled from its finished units' part records:
``meta/info.json``, ``stats.json``, tasks, episodes (a Parquet table in v3.0; JSON lines
and GR00T's ``modality.json`` in v2.1) and ``meta/dyana.json``, written last, which lists
every file with its sha256 and size and marks the export finished.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from catalog.export.camera import CAMERA_META, camera_meta
from catalog.export.card import CITATION, KEYWORDS, LICENSE_URL, description, readme, title
from catalog.export.croissant import CROISSANT, croissant
from catalog.export.episode_stats import Moments, merge_all
from catalog.export.layout import (
    DYANA_META,
    V21_DATA_PATH,
    V21_VIDEO_PATH,
    V30_DATA_PATH,
    V30_EPISODES_PATH,
    V30_VIDEO_PATH,
    VIDEO_KEY,
    features,
    modality,
    vector_names,
)
from catalog.export.lerobot import ExportSettings, Json, Part
from catalog.loader.lerobot_names import IMAGE_SOURCE, VECTOR_SOURCES
from catalog.store.atomic import atomic_open, atomic_write_text
from catalog.store.hashing import sha256_file
from catalog.tables.reader import FolderReader
from catalog.tables.stats import load_stats
from schemas.versions import CODE_VERSION, FPS


def tasks_of(readers: Sequence[FolderReader]) -> dict[str, int]:
    """Each distinct task text of the sources' episodes, numbered in order of appearance."""
    texts = [text for reader in readers for text in reader.episodes(["text"]).column("text").to_pylist()]
    return {text: i for i, text in enumerate(dict.fromkeys(texts))}


def _merged_stats(parts: Sequence[Part], readers: Sequence[FolderReader], environment_state: bool) -> dict[str, Any]:
    """``meta/stats.json``: everything merged over episodes; from one source, states and
    actions are its own ``stats.json``'s numbers (concatenated per LeRobot feature)."""
    per_episode = [e["stats"] for part in parts for e in part.episodes]
    out: dict[str, Any] = {}
    for key in per_episode[0]:
        out[key] = merge_all([Moments.from_state(s[key]) for s in per_episode]).to_dict()
    if len(readers) != 1:
        return out
    dyana = load_stats(readers[0].root)
    for key in vector_names(environment_state):
        sources = VECTOR_SOURCES[key]
        columns = [dyana.columns[name] for name in sources]
        out[key] = {
            "min": np.concatenate([c.min for c in columns]).tolist(),
            "max": np.concatenate([c.max for c in columns]).tolist(),
            "mean": np.concatenate([c.mean for c in columns]).tolist(),
            "std": np.concatenate([c.std for c in columns]).tolist(),
            "count": [columns[0].count],
        }
    return out


def _episode_stats_dict(state: dict[str, Any]) -> dict[str, Any]:
    return {key: Moments.from_state(s).to_dict() for key, s in state.items()}


def _plain(value: Any) -> Any:
    """Mappings and sequences as plain dicts and lists (manifests hold read-only views)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _write_json(path: Path, data: Any) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True, allow_nan=False) + "\n")


def _tasks_table(tasks: Mapping[str, int]) -> pa.Table:
    """``meta/tasks.parquet`` as LeRobot reads it with pandas: task strings as the index."""
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode", "numpy_type": "object",
                            "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64",
             "metadata": None},
            {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": None},
        ],
        "attributes": {},
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.0",
    }
    schema = pa.schema([pa.field("task_index", pa.int64()), pa.field("task", pa.string())],
                       metadata={"pandas": json.dumps(pandas_meta)})
    return pa.table({"task_index": list(tasks.values()), "task": list(tasks)}, schema=schema)


def _write_table(path: Path, table: pa.Table) -> None:
    with atomic_open(path, "wb") as handle:
        pq.write_table(table, handle, compression="zstd")


def _v30_episodes_table(parts: Sequence[Part]) -> pa.Table:
    rows = []
    for part in parts:
        for e in part.episodes:
            row = {
                "episode_index": e["episode_index"],
                "tasks": e["tasks"],
                "length": e["length"],
                "data/chunk_index": e["chunk_index"],
                "data/file_index": e["file_index"],
                "dataset_from_index": e["dataset_from_index"],
                "dataset_to_index": e["dataset_to_index"],
                f"videos/{VIDEO_KEY}/chunk_index": e["chunk_index"],
                f"videos/{VIDEO_KEY}/file_index": e["file_index"],
                f"videos/{VIDEO_KEY}/from_timestamp": e["from_timestamp"],
                f"videos/{VIDEO_KEY}/to_timestamp": e["to_timestamp"],
                "meta/episodes/chunk_index": 0,
                "meta/episodes/file_index": 0,
            }
            for key, stats in _episode_stats_dict(e["stats"]).items():
                for name, value in stats.items():
                    row[f"stats/{key}/{name}"] = value
            row.update({k: v for k, v in e.items() if k.startswith("dyana/")})
            rows.append(row)
    return pa.Table.from_pylist(rows)


def _source(reader: FolderReader, first_episode: int) -> dict[str, Any]:
    manifest = reader.manifest
    return _plain({"slice": manifest.slice, "slice_hash": manifest.hash, "episodes": manifest.episodes,
                   "first_episode": first_episode, "settings": manifest.settings, "extra": manifest.extra})


def assemble(out: Path, readers: Sequence[FolderReader], settings: ExportSettings, parts: Sequence[Part],
             tasks: Mapping[str, int], identity: Mapping[str, Json], height: int, width: int) -> None:
    """Write the export's metadata from its finished parts, ``meta/dyana.json`` last."""
    episodes = sum(len(p.episodes) for p in parts)
    frames = sum(p.frames for p in parts)
    meta = out / "meta"
    files: dict[str, dict[str, Any]] = {}
    for part in parts:
        files.update({f.path: {"sha256": f.sha256, "size": f.size} for f in part.files})

    def written(path: Path) -> None:
        files[path.relative_to(out).as_posix()] = {"sha256": sha256_file(path), "size": path.stat().st_size}

    info: dict[str, Any] = {
        "codebase_version": settings.version,
        "robot_type": "dyana_hand",
        "total_episodes": episodes,
        "total_frames": frames,
        "total_tasks": len(tasks),
        "chunks_size": 1000,
        "fps": FPS,
        "splits": {"train": f"0:{episodes}"},
        "features": features(height, width, FPS, settings.codec, settings.version, settings.environment_state),
    }
    _write_json(meta / "stats.json", _merged_stats(parts, readers, settings.environment_state))
    written(meta / "stats.json")
    if settings.version == "v3.0":
        info.update({
            "data_files_size_in_mb": 100,
            "video_files_size_in_mb": 200,
            "data_path": V30_DATA_PATH,
            "video_path": V30_VIDEO_PATH,
        })
        _write_table(meta / "tasks.parquet", _tasks_table(tasks))
        written(meta / "tasks.parquet")
        _write_table(out / V30_EPISODES_PATH, _v30_episodes_table(parts))
        written(out / V30_EPISODES_PATH)
    else:
        info.update({
            "total_videos": episodes,
            "total_chunks": (episodes + 999) // 1000,
            "data_path": V21_DATA_PATH,
            "video_path": V21_VIDEO_PATH,
        })
        lines = [json.dumps({"task_index": i, "task": t}) for t, i in tasks.items()]
        atomic_write_text(meta / "tasks.jsonl", "\n".join(lines) + "\n")
        episode_lines, stats_lines = [], []
        for part in parts:
            for e in part.episodes:
                facts = {k: v for k, v in e.items() if k.startswith("dyana/")}
                episode_lines.append(json.dumps({"episode_index": e["episode_index"], "tasks": e["tasks"],
                                                 "length": e["length"], **facts}, sort_keys=True))
                stats_lines.append(json.dumps({"episode_index": e["episode_index"],
                                               "stats": _episode_stats_dict(e["stats"])}, sort_keys=True))
        atomic_write_text(meta / "episodes.jsonl", "\n".join(episode_lines) + "\n")
        atomic_write_text(meta / "episodes_stats.jsonl", "\n".join(stats_lines) + "\n")
        _write_json(meta / "modality.json", modality(settings.version))
        for name in ("tasks.jsonl", "episodes.jsonl", "episodes_stats.jsonl", "modality.json"):
            written(meta / name)
    _write_json(meta / "info.json", info)
    written(meta / "info.json")
    _write_json(out / CAMERA_META, camera_meta(height, width))
    written(out / CAMERA_META)
    atomic_write_text(out / "README.md", readme(readers, asdict(settings), settings.version, episodes, frames, height,
                                                width))
    written(out / "README.md")
    _write_json(out / CROISSANT, croissant(title(readers), description(readers, episodes, frames, settings.version),
                                           LICENSE_URL, CITATION, CODE_VERSION, settings.version, files,
                                           settings.environment_state, KEYWORDS))
    written(out / CROISSANT)
    firsts = np.cumsum([0] + [r.manifest.episodes for r in readers]).tolist()
    _write_json(out / DYANA_META, {
        "job": dict(identity),
        "sources": [_source(reader, int(first)) for reader, first in zip(readers, firsts)],
        "code_version": CODE_VERSION,
        "mapping": {key: list(VECTOR_SOURCES[key]) for key in vector_names(settings.environment_state)}
        | {VIDEO_KEY: [IMAGE_SOURCE]},
        "files": dict(sorted(files.items())),
    })

