"""``catalog export DIR --format lerobot|lerobot-v2.1 --out OUT``: a built slice or an
evaluated run as a LeRobot dataset (the field mapping is in :mod:`catalog.export.layout`).

Work is done shard by shard (a *unit*): in v3.0 a Dyana shard becomes one data file
and one video file (``file-<shard>``), in v2.1 one data and one video file per
episode. A finished unit leaves a part record (its episodes' metadata, statistics and
files with their sha256) in ``OUT/.dyana-export/``; an interrupted export resumes from
the units whose files are intact. When every unit is done the metadata is assembled
(``meta/info.json``, ``stats.json``, tasks, episodes, GR00T's ``modality.json`` for
v2.1) and ``meta/dyana.json`` is written last: it lists every file with its sha256 and
marks the export finished. The same source and settings give the same bytes
(:mod:`catalog.export.video`); the codec build is recorded.

A folder holds one export: an existing finished export of the same source and
settings is "up to date"; anything else in ``OUT`` is refused unless ``--overwrite``
(which only ever deletes a folder that is a Dyana export).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path
from queue import Empty
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from catalog.atomic import atomic_open, atomic_write_text
from catalog.export.episode_stats import Moments, merge_all
from catalog.export.layout import (
    DYANA_META,
    EPISODE_FACTS,
    FORMATS,
    INDEX_FEATURES,
    ROLLOUT_FACTS,
    V21_DATA_PATH,
    V21_VIDEO_PATH,
    V30_DATA_PATH,
    V30_EPISODES_PATH,
    V30_VIDEO_PATH,
    VECTOR_NAMES,
    VECTOR_SOURCES,
    VIDEO_KEY,
    chunk_of,
    features,
    modality,
)
from catalog.export.video import CODECS, VideoWriter, codec_versions
from catalog.hashing import sha256_file
from catalog.parquet_io import column_to_numpy
from catalog.reader import FolderReader, ShardReader, open_folder
from catalog.stats import load_stats
from schemas.cli import ProgressMeter
from schemas.errors import DyanaError
from schemas.names import shorten
from schemas.versions import CODE_VERSION, FPS

WORK_DIR = ".dyana-export"
EXPORT_VERSION = 1
_IMREAD = getattr(cv2, "IMREAD_COLOR_RGB", None)


class ExportError(DyanaError):
    """The export cannot be made into this folder, or its source cannot be read."""


@dataclass(frozen=True)
class ExportSettings:
    """What decides an export's bytes besides its source."""

    format: str
    codec: str = "h264"

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise ExportError(f"--format {shorten(repr(self.format))}: expected one of {sorted(FORMATS)}")
        if self.codec not in CODECS:
            raise ExportError(f"--codec {shorten(repr(self.codec))}: expected one of {sorted(CODECS)}")

    @property
    def version(self) -> str:
        return FORMATS[self.format]


@dataclass(frozen=True)
class Unit:
    """One shard's share of the export: everything a worker process needs."""

    source: str
    shard: int
    first_index: int
    tasks: dict[str, int]
    settings: ExportSettings
    out: str
    height: int
    width: int


@dataclass(frozen=True)
class ExportReport:
    out: Path
    episodes: int
    frames: int
    units_done: int
    units_resumed: int
    up_to_date: bool
    seconds: float


def _decode(jpeg: bytes) -> np.ndarray:
    data = np.frombuffer(jpeg, dtype=np.uint8)
    if _IMREAD is not None:
        image = cv2.imdecode(data, _IMREAD)
    else:  # pragma: no cover - older OpenCV
        image = cv2.imdecode(data, cv2.IMREAD_COLOR)
        image = None if image is None else image[:, :, ::-1]
    if image is None:
        raise ExportError("a frame's JPEG does not decode")
    return np.ascontiguousarray(image)


def _hf_features() -> dict[str, Any]:
    """The ``huggingface`` schema metadata `datasets` reads the data files' features from."""
    out: dict[str, Any] = {}
    for key, names in VECTOR_NAMES.items():
        out[key] = {"feature": {"dtype": "float32", "_type": "Value"}, "length": len(names), "_type": "Sequence"}
    out["timestamp"] = {"dtype": "float32", "_type": "Value"}
    for key in INDEX_FEATURES[1:]:
        out[key] = {"dtype": "int64", "_type": "Value"}
    return {"info": {"features": out}}


_DATA_SCHEMA = pa.schema(
    [pa.field(key, pa.list_(pa.float32(), len(names))) for key, names in VECTOR_NAMES.items()]
    + [pa.field("timestamp", pa.float32())]
    + [pa.field(key, pa.int64()) for key in INDEX_FEATURES[1:]],
    metadata={"huggingface": json.dumps(_hf_features(), sort_keys=True)},
)


def _vector(columns: dict[str, np.ndarray], key: str, rows: slice) -> np.ndarray:
    return np.concatenate([columns[name][rows] for name in VECTOR_SOURCES[key]], axis=1).astype(np.float32)


def _data_table(columns: dict[str, np.ndarray], rows: slice, episode: int, first_index: int, task: int) -> pa.Table:
    n = rows.stop - rows.start
    frame_index = columns["frame_index"][rows].astype(np.int64)
    arrays = []
    for key, names in VECTOR_NAMES.items():
        values = _vector(columns, key, rows)
        arrays.append(pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1), pa.float32()), len(names)))
    arrays.append(pa.array((frame_index / FPS).astype(np.float32), pa.float32()))
    arrays.append(pa.array(frame_index, pa.int64()))
    arrays.append(pa.array(np.full(n, episode, dtype=np.int64), pa.int64()))
    arrays.append(pa.array(np.arange(first_index, first_index + n, dtype=np.int64), pa.int64()))
    arrays.append(pa.array(np.full(n, task, dtype=np.int64), pa.int64()))
    return pa.Table.from_arrays(arrays, schema=_DATA_SCHEMA)


def _write_parquet(path: Path, tables: list[pa.Table]) -> None:
    with atomic_open(path, "wb") as handle:
        with pq.ParquetWriter(handle, _DATA_SCHEMA, compression="zstd", write_statistics=True) as writer:
            for table in tables:
                writer.write_table(table, row_group_size=max(table.num_rows, 1))


def _episode_stats(columns: dict[str, np.ndarray], rows: slice, images: np.ndarray, index: np.ndarray,
                   episode: int, task: int) -> dict[str, Moments]:
    n = rows.stop - rows.start
    frame_index = columns["frame_index"][rows].astype(np.float64)
    stats = {key: Moments.of(_vector(columns, key, rows)) for key in VECTOR_NAMES}
    stats[VIDEO_KEY] = Moments.of_images(images)
    stats["timestamp"] = Moments.of((frame_index / FPS)[:, None])
    stats["frame_index"] = Moments.of(frame_index[:, None])
    stats["episode_index"] = Moments.of(np.full((n, 1), float(episode)))
    stats["index"] = Moments.of(index.astype(np.float64)[:, None])
    stats["task_index"] = Moments.of(np.full((n, 1), float(task)))
    return stats


def _facts(row: dict[str, Any]) -> dict[str, Any]:
    return {f"dyana/{name}": row[name] for name in EPISODE_FACTS + ROLLOUT_FACTS if name in row}


#: Where :func:`export_unit` reports each exported episode as ``(shard, episodes, frames)``
#: done in its unit (progress lines only; set by :func:`export` in this process or by the
#: pool's initializer in a worker process).
_episode_sink: Callable[[int, int, int], None] | None = None


def _report_to(queue: Any) -> None:
    """Pool initializer: episode reports go to ``queue`` (none without one)."""
    global _episode_sink
    _episode_sink = None if queue is None else lambda shard, done, frames: queue.put((shard, done, frames))


@contextlib.contextmanager
def _episodes_to(sink: Callable[[int, int, int], None] | None) -> Iterator[None]:
    """Within the block, :func:`export_unit` in this process reports episodes to ``sink``."""
    global _episode_sink
    previous, _episode_sink = _episode_sink, sink
    try:
        yield
    finally:
        _episode_sink = previous


def export_unit(unit: Unit) -> dict[str, Any]:
    """Export one shard; returns its part record (episodes, statistics, files)."""
    reader = open_folder(unit.source, verify="sha256")
    shard: ShardReader = reader.shards[unit.shard]
    episodes = shard.episodes()
    names = ("image", "frame_index", "palm_pose", "joint_angles", "object_pose", "action")
    table, runs = shard.indexed_frames(names, episodes)
    columns = {name: column_to_numpy(table.column(name)) for name in names if name != "image"}
    jpegs = table.column("image")
    out = Path(unit.out)
    v30 = unit.settings.version == "v3.0"
    chunk, file_index = chunk_of(unit.shard)
    records, files = [], []
    data_tables: list[pa.Table] = []
    next_index = unit.first_index
    video: VideoWriter | None = None
    if v30:
        video_path = out / V30_VIDEO_PATH.format(video_key=VIDEO_KEY, chunk_index=chunk, file_index=file_index)
        video = VideoWriter(video_path, unit.width, unit.height, FPS, unit.settings.codec)
    try:
        for row in episodes.to_pylist():
            episode = int(row["episode_index"])
            first, count = runs[episode]
            rows = slice(first, first + count)
            images = np.stack([_decode(jpegs[k].as_py()) for k in range(first, first + count)])
            task = unit.tasks[row["text"]]
            index = np.arange(next_index, next_index + count, dtype=np.int64)
            data = _data_table(columns, rows, episode, next_index, task)
            record: dict[str, Any] = {
                "episode_index": episode,
                "tasks": [row["text"]],
                "length": count,
                "dataset_from_index": next_index,
                "dataset_to_index": next_index + count,
                "stats": {k: m.to_state() for k, m in _episode_stats(columns, rows, images, index, episode, task).items()},
                **_facts(row),
            }
            if v30:
                assert video is not None
                record["from_timestamp"] = video.frames / FPS
                for image in images:
                    video.add(image)
                record["to_timestamp"] = video.frames / FPS
                record["chunk_index"], record["file_index"] = chunk, file_index
                data_tables.append(data)
            else:
                episode_chunk = episode // 1000
                data_path = out / V21_DATA_PATH.format(episode_chunk=episode_chunk, episode_index=episode)
                _write_parquet(data_path, [data])
                video_path = out / V21_VIDEO_PATH.format(episode_chunk=episode_chunk, video_key=VIDEO_KEY,
                                                         episode_index=episode)
                with VideoWriter(video_path, unit.width, unit.height, FPS, unit.settings.codec) as writer:
                    for image in images:
                        writer.add(image)
                files += [data_path, video_path]
            records.append(record)
            next_index += count
            if _episode_sink is not None:
                with contextlib.suppress(Exception):  # progress never fails an export
                    _episode_sink(unit.shard, len(records), next_index - unit.first_index)
        if v30:
            assert video is not None
            video.finish()
            video = None
            data_path = out / V30_DATA_PATH.format(chunk_index=chunk, file_index=file_index)
            _write_parquet(data_path, data_tables)
            files += [data_path, out / V30_VIDEO_PATH.format(video_key=VIDEO_KEY, chunk_index=chunk, file_index=file_index)]
    finally:
        if video is not None:
            video.__exit__(RuntimeError, None, None)
    part = {
        "shard": unit.shard,
        "episodes": records,
        "files": {p.relative_to(out).as_posix(): {"sha256": sha256_file(p), "size": p.stat().st_size} for p in files},
    }
    text = json.dumps(part, sort_keys=True)
    atomic_write_text(out / WORK_DIR / f"part-{unit.shard:05d}.json", text + "\n")
    return json.loads(text)  # the same canonical form a resumed export reads back


# --- the job --------------------------------------------------------------------------------


def _job_identity(reader: FolderReader, settings: ExportSettings) -> dict[str, Any]:
    return {
        "export_version": EXPORT_VERSION,
        "source_hash": reader.manifest.hash,
        "slice": reader.manifest.slice,
        "settings": asdict(settings),
        "codec": codec_versions(settings.codec),
    }


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    work = out / WORK_DIR
    work.mkdir(parents=True, exist_ok=True)
    with open(work / "lock", "a+") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise ExportError(f"{shorten(os.fspath(out))}: another export is writing into this folder") from None
        try:
            yield
        finally:
            # A finished or refused export leaves no trace of the lock; an unfinished one
            # keeps its work folder (job and parts) for the next run to resume.
            with contextlib.suppress(OSError):
                (work / "lock").unlink()
                work.rmdir()


def _is_export(out: Path) -> bool:
    return (out / DYANA_META).is_file() or (out / WORK_DIR / "job.json").is_file()


def _check_foreign(out: Path) -> None:
    """Refuse, before writing anything, a folder that holds something other than an export."""
    if out.is_dir() and not _is_export(out) and any(child.name != WORK_DIR for child in out.iterdir()):
        raise ExportError(f"{shorten(os.fspath(out))}: not empty and not a Dyana export; choose a new folder")
    if out.exists() and not out.is_dir():
        raise ExportError(f"{shorten(os.fspath(out))}: exists and is not a folder")


def _prepare(out: Path, identity: dict[str, Any], overwrite: bool) -> bool:
    """Check what ``out`` holds; True when it is a finished export of the same job."""
    finished = out / DYANA_META
    job = out / WORK_DIR / "job.json"
    is_export = finished.is_file() or job.is_file()
    if finished.is_file():
        meta = json.loads(finished.read_text())
        if meta.get("job") == identity and not overwrite:
            return True
    if any(child.name != WORK_DIR for child in out.iterdir()):
        if not is_export:
            raise ExportError(f"{shorten(os.fspath(out))}: not empty and not a Dyana export; choose a new folder")
        same_job = job.is_file() and json.loads(job.read_text()) == identity and not finished.is_file()
        if not same_job:
            if not overwrite:
                raise ExportError(
                    f"{shorten(os.fspath(out))}: holds an export of another source or settings; "
                    "use --overwrite to replace it"
                )
            for child in out.iterdir():
                if child.name != WORK_DIR:
                    shutil.rmtree(child) if child.is_dir() else child.unlink()
            for child in (out / WORK_DIR).glob("part-*.json"):
                child.unlink()
    (out / WORK_DIR).mkdir(parents=True, exist_ok=True)
    atomic_write_text(job, json.dumps(identity, sort_keys=True) + "\n")
    return False


def _intact_part(out: Path, shard: int) -> dict[str, Any] | None:
    path = out / WORK_DIR / f"part-{shard:05d}.json"
    if not path.is_file():
        return None
    try:
        part = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    for name, record in part.get("files", {}).items():
        file = out / name
        if not file.is_file() or file.stat().st_size != record["size"] or sha256_file(file) != record["sha256"]:
            return None
    return part


def _tasks(reader: FolderReader) -> dict[str, int]:
    texts = reader.episodes(["text"]).column("text").to_pylist()
    return {text: i for i, text in enumerate(dict.fromkeys(texts))}


def _merged_stats(parts: list[dict[str, Any]], reader: FolderReader) -> dict[str, Any]:
    """``meta/stats.json``: states and actions from the folder's own ``stats.json`` (the
    same numbers, concatenated per LeRobot feature); the rest merged over episodes."""
    per_episode = [e["stats"] for part in parts for e in part["episodes"]]
    out: dict[str, Any] = {}
    for key in per_episode[0]:
        out[key] = merge_all([Moments.from_state(s[key]) for s in per_episode]).to_dict()
    dyana = load_stats(reader.root)
    for key, sources in VECTOR_SOURCES.items():
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


def _tasks_table(tasks: dict[str, int]) -> pa.Table:
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


def _v30_episodes_table(parts: list[dict[str, Any]]) -> pa.Table:
    rows = []
    for part in parts:
        for e in part["episodes"]:
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


def _assemble(out: Path, reader: FolderReader, settings: ExportSettings, parts: list[dict[str, Any]],
              tasks: dict[str, int], identity: dict[str, Any], height: int, width: int) -> None:
    episodes = sum(len(p["episodes"]) for p in parts)
    frames = sum(e["length"] for p in parts for e in p["episodes"])
    meta = out / "meta"
    files: dict[str, dict[str, Any]] = {}
    for part in parts:
        files.update(part["files"])

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
        "features": features(height, width, FPS, settings.codec, settings.version),
    }
    _write_json(meta / "stats.json", _merged_stats(parts, reader))
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
            for e in part["episodes"]:
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
    manifest = reader.manifest
    _write_json(out / DYANA_META, {
        "job": identity,
        "source": _plain({"slice": manifest.slice, "slice_hash": manifest.hash, "episodes": manifest.episodes,
                          "settings": manifest.settings, "extra": manifest.extra}),
        "code_version": CODE_VERSION,
        "mapping": {key: list(sources) for key, sources in VECTOR_SOURCES.items()} | {VIDEO_KEY: ["image"]},
        "files": dict(sorted(files.items())),
    })


def export(
    source: str | os.PathLike[str],
    out: str | os.PathLike[str],
    settings: ExportSettings,
    *,
    workers: int = 1,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
) -> ExportReport:
    """Export a built slice or run folder into ``out`` (see the module docstring)."""
    start = time.perf_counter()
    reader = open_folder(source, verify="sha256")
    if reader.manifest.episodes == 0:
        raise ExportError(f"{shorten(os.fspath(source))}: nothing to export (no episodes)")
    target = Path(out)
    identity = _job_identity(reader, settings)
    _check_foreign(target)
    target.mkdir(parents=True, exist_ok=True)
    with _locked(target):
        if _prepare(target, identity, overwrite):
            return ExportReport(target, reader.manifest.episodes, reader.manifest.frames,
                                0, 0, True, time.perf_counter() - start)
        height = width = int(reader.manifest.settings.get("resolution", 0))
        if height <= 0 or height % 2:
            raise ExportError(f"{shorten(os.fspath(source))}: video export needs an even image size, got {height}")
        tasks = _tasks(reader)
        firsts = np.concatenate([[0], np.cumsum([s.frames for s in reader.manifest.shards])]).astype(int)
        units = [Unit(str(reader.root), k, int(firsts[k]), tasks, settings, os.fspath(target), height, width)
                 for k in range(len(reader.shards))]
        parts: dict[int, dict[str, Any]] = {}
        for unit in units:
            part = _intact_part(target, unit.shard)
            if part is not None:
                parts[unit.shard] = part
        resumed = len(parts)
        todo = [u for u in units if u.shard not in parts]
        total_frames = int(firsts[-1])
        done_frames = sum(e["length"] for p in parts.values() for e in p["episodes"])
        say = progress or (lambda line: None)
        if resumed:
            say(f"[resuming: {resumed}/{len(units)} shards already exported]")
        meter = None
        if progress is not None:
            meter = ProgressMeter(reader.manifest.episodes, total_frames=total_frames, say=progress)
            meter.resume(sum(len(p["episodes"]) for p in parts.values()), done_frames)
        running: dict[int, tuple[int, int]] = {}  # shard -> (episodes, frames) exported so far

        def show() -> None:
            if meter is not None:
                episodes = sum(len(p["episodes"]) for p in parts.values()) + sum(r[0] for r in running.values())
                frames = done_frames + sum(r[1] for r in running.values())
                meter.update(episodes, frames, prefix=f"[{len(parts)}/{len(units)} shards]",
                             last=len(parts) == len(units))

        def episode_done(shard: int, done: int, frames: int) -> None:
            if shard not in parts and done > running.get(shard, (0, 0))[0]:
                running[shard] = (done, frames)
                show()

        def report(part: dict[str, Any]) -> None:
            nonlocal done_frames
            parts[part["shard"]] = part
            running.pop(part["shard"], None)
            done_frames += sum(e["length"] for e in part["episodes"])
            show()

        if workers > 1 and len(todo) > 1:
            context = get_context("spawn")
            queue = context.Queue() if meter is not None else None
            with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_report_to,
                                     initargs=(queue,)) as pool:
                pending = {pool.submit(export_unit, unit) for unit in todo}
                while pending:
                    finished, pending = wait(pending, timeout=0.25, return_when=FIRST_COMPLETED)
                    while queue is not None:
                        try:
                            episode_done(*queue.get_nowait())
                        except Empty:
                            break
                    for future in finished:
                        report(future.result())
        else:
            with _episodes_to(episode_done if meter is not None else None):
                for unit in todo:
                    report(export_unit(unit))
        ordered = [parts[k] for k in range(len(units))]
        _assemble(target, reader, settings, ordered, tasks, identity, height, width)
        for part_file in (target / WORK_DIR).glob("part-*.json"):
            part_file.unlink()
        (target / WORK_DIR / "job.json").unlink()
    episodes = sum(len(p["episodes"]) for p in ordered)
    return ExportReport(target, episodes, total_frames, len(todo), resumed, False, time.perf_counter() - start)


def print_progress(line: str) -> None:
    print(line, file=sys.stderr, flush=True)
