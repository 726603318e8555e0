"""One unit of a LeRobot export: one source shard's episodes as data and video files,
and its part record (:class:`catalog.export.lerobot.Part`).

In v3.0 the shard becomes one data file and one video file (``file-<unit>``), in v2.1
one data and one video file per episode. Episodes are numbered as the export numbers them
(:class:`catalog.export.lerobot.Unit`); each keeps its source's hash and episode index. The part record is written last, so a unit
whose part record is there (and whose files still match it) is finished.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from catalog.export.episode_stats import Moments
from catalog.export.layout import (
    EPISODE_FACTS,
    PROVENANCE,
    ROLLOUT_FACTS,
    V21_DATA_PATH,
    V21_VIDEO_PATH,
    V30_DATA_PATH,
    V30_VIDEO_PATH,
    VECTOR_NAMES,
    VIDEO_KEY,
    chunk_of,
    vector_names,
)
from catalog.export.lerobot import ExportError, ExportPlan, Json, Part, Unit, json_int, part_path
from catalog.export.video import VideoWriter
from catalog.loader.lerobot_names import IMAGE_SOURCE, INDEX_FEATURES, VECTOR_SOURCES
from catalog.store.atomic import atomic_open, atomic_write_text
from catalog.store.hashing import sha256_file
from catalog.store.records import FileRecord
from catalog.tables.parquet_io import column_to_numpy
from catalog.tables.reader import ShardReader, open_folder
from schemas.versions import FPS

_IMREAD = getattr(cv2, "IMREAD_COLOR_RGB", None)

#: ``(first, end, done, frames)``: ``done`` episodes (``frames`` frames) of the unit of
#: source episodes [first, end) are exported (progress only).
EpisodeReport = Callable[[int, int, int, int], None]


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


def _checked(image: np.ndarray, plan: ExportPlan, shard: ShardReader, episode: int, frame: int) -> np.ndarray:
    """``image`` if it has the size the source's settings give (the video's size), else an
    ExportError naming the source file: settings edited to another resolution (and re-hashed)
    would otherwise fail in the encoder, naming the export's own video."""
    if image.shape[:2] != (plan.height, plan.width):
        raise ExportError(f"{shard.path('frames')}: episode {episode} frame {frame} is {image.shape[1]}x{image.shape[0]} px, "
                          f"but catalog.json's settings say resolution {plan.height}: the folder's settings do not "
                          "match its images")
    return image


def _hf_features(vectors: dict[str, tuple[str, ...]]) -> dict[str, Json]:
    """The ``huggingface`` schema metadata `datasets` reads the data files' features from."""
    out: dict[str, Json] = {}
    for key, names in vectors.items():
        out[key] = {"feature": {"dtype": "float32", "_type": "Value"}, "length": len(names), "_type": "Sequence"}
    out["timestamp"] = {"dtype": "float32", "_type": "Value"}
    for key in INDEX_FEATURES[1:]:
        out[key] = {"dtype": "int64", "_type": "Value"}
    return {"info": {"features": out}}


def data_schema(environment_state: bool) -> pa.Schema:
    """The data files' schema: the vectors exported, then the index columns."""
    vectors = vector_names(environment_state)
    return pa.schema(
        [pa.field(key, pa.list_(pa.float32(), len(names))) for key, names in vectors.items()]
        + [pa.field("timestamp", pa.float32())]
        + [pa.field(key, pa.int64()) for key in INDEX_FEATURES[1:]],
        metadata={"huggingface": json.dumps(_hf_features(vectors), sort_keys=True)},
    )


def _vector(columns: dict[str, np.ndarray], key: str, rows: slice) -> np.ndarray:
    return np.concatenate([columns[name][rows] for name in VECTOR_SOURCES[key]], axis=1).astype(np.float32)


def _data_table(schema: pa.Schema, columns: dict[str, np.ndarray], rows: slice, episode: int, first_index: int,
                task: int) -> pa.Table:
    n = rows.stop - rows.start
    frame_index = columns["frame_index"][rows].astype(np.int64)
    arrays = []
    for field in schema:
        if field.name not in VECTOR_SOURCES:
            break
        key, names = field.name, VECTOR_NAMES[field.name]
        values = _vector(columns, key, rows)
        arrays.append(pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1), pa.float32()), len(names)))
    arrays.append(pa.array((frame_index / FPS).astype(np.float32), pa.float32()))
    arrays.append(pa.array(frame_index, pa.int64()))
    arrays.append(pa.array(np.full(n, episode, dtype=np.int64), pa.int64()))
    arrays.append(pa.array(np.arange(first_index, first_index + n, dtype=np.int64), pa.int64()))
    arrays.append(pa.array(np.full(n, task, dtype=np.int64), pa.int64()))
    return pa.Table.from_arrays(arrays, schema=schema)


def _write_parquet(path: Path, schema: pa.Schema, tables: list[pa.Table]) -> None:
    with atomic_open(path, "wb") as handle:
        with pq.ParquetWriter(handle, schema, compression="zstd", write_statistics=True) as writer:
            for table in tables:
                writer.write_table(table, row_group_size=max(table.num_rows, 1))


def _episode_stats(vectors: dict[str, tuple[str, ...]], columns: dict[str, np.ndarray], rows: slice,
                   images: np.ndarray, index: np.ndarray, episode: int, task: int) -> dict[str, Moments]:
    n = rows.stop - rows.start
    frame_index = columns["frame_index"][rows].astype(np.float64)
    stats = {key: Moments.of(_vector(columns, key, rows)) for key in vectors}
    stats[VIDEO_KEY] = Moments.of_images(images)
    stats["timestamp"] = Moments.of((frame_index / FPS)[:, None])
    stats["frame_index"] = Moments.of(frame_index[:, None])
    stats["episode_index"] = Moments.of(np.full((n, 1), float(episode)))
    stats["index"] = Moments.of(index.astype(np.float64)[:, None])
    stats["task_index"] = Moments.of(np.full((n, 1), float(task)))
    return stats


def _facts(row: dict[str, Json]) -> dict[str, Json]:
    return {f"dyana/{name}": row[name] for name in EPISODE_FACTS + ROLLOUT_FACTS if name in row}


def export_unit(plan: ExportPlan, first: int, report: EpisodeReport | None = None) -> Part:
    """Export the unit whose first exported episode is ``first``; its part record, written
    last. ``report`` hears each exported episode (progress only: its failure is ignored)."""
    number, unit = plan.unit_at(first)
    reader = open_folder(plan.sources[unit.source], verify="sha256")
    if reader.manifest.hash != plan.hashes[unit.source]:
        raise ExportError(f"{plan.sources[unit.source]}: changed since the export started (its slice hash differs)")
    shard = next(s for s in reader.shards if s.record.first == unit.source_first)
    episodes = shard.episodes()
    names = (IMAGE_SOURCE, "frame_index", *(name for sources in VECTOR_SOURCES.values() for name in sources))
    table, runs = shard.indexed_frames(names, episodes)
    columns = {name: column_to_numpy(table.column(name)) for name in names if name != IMAGE_SOURCE}
    out = Path(plan.out)
    records, files = _write_episodes(plan, number, unit, shard, episodes.to_pylist(), table.column(IMAGE_SOURCE), runs,
                                     columns, out, report)
    part = Part(number, tuple(records),
                tuple(FileRecord(p.relative_to(out).as_posix(), sha256_file(p), p.stat().st_size) for p in files))
    text = json.dumps(part.to_dict(), sort_keys=True)
    atomic_write_text(part_path(out, number), text + "\n")
    return Part.from_dict(json.loads(text))  # the same canonical form a resumed export reads back


def _write_episodes(plan: ExportPlan, number: int, unit: Unit, shard: ShardReader, rows: list[dict[str, Json]],
                    jpegs: pa.ChunkedArray, runs: dict[int, tuple[int, int]], columns: dict[str, np.ndarray], out: Path,
                    report: EpisodeReport | None) -> tuple[list[dict[str, Json]], list[Path]]:
    """The unit's data and video files; each episode's record and the files written."""
    v30 = plan.settings.version == "v3.0"
    schema = data_schema(plan.settings.environment_state)
    vectors = vector_names(plan.settings.environment_state)
    chunk, file_index = chunk_of(number)
    first_index = next_index = unit.index
    records: list[dict[str, Json]] = []
    files: list[Path] = []
    data_tables: list[pa.Table] = []
    video: VideoWriter | None = None
    if v30:
        video_path = out / V30_VIDEO_PATH.format(video_key=VIDEO_KEY, chunk_index=chunk, file_index=file_index)
        video = VideoWriter(video_path, plan.width, plan.height, FPS, plan.settings.codec)
    try:
        for position, row in enumerate(rows):
            source_episode = json_int(row["episode_index"])
            episode = unit.episode + position
            start, count = runs[source_episode]
            span = slice(start, start + count)
            images = np.stack([_checked(_decode(jpegs[k].as_py()), plan, shard, source_episode, k - start)
                               for k in range(start, start + count)])
            task = plan.tasks[str(row["text"])]
            index = np.arange(next_index, next_index + count, dtype=np.int64)
            data = _data_table(schema, columns, span, episode, next_index, task)
            record: dict[str, Json] = {
                "episode_index": episode,
                "tasks": [row["text"]],
                "length": count,
                "dataset_from_index": next_index,
                "dataset_to_index": next_index + count,
                "stats": {k: m.to_state()
                          for k, m in _episode_stats(vectors, columns, span, images, index, episode, task).items()},
                **_facts(row),
                **dict(zip((f"dyana/{name}" for name in PROVENANCE), (plan.hashes[unit.source], source_episode))),
            }
            if video is not None:
                record["from_timestamp"] = video.frames / FPS
                for image in images:
                    video.add(image)
                record["to_timestamp"] = video.frames / FPS
                record["chunk_index"], record["file_index"] = chunk, file_index
                data_tables.append(data)
            else:
                episode_chunk = episode // 1000
                data_path = out / V21_DATA_PATH.format(episode_chunk=episode_chunk, episode_index=episode)
                _write_parquet(data_path, schema, [data])
                video_path = out / V21_VIDEO_PATH.format(episode_chunk=episode_chunk, video_key=VIDEO_KEY,
                                                         episode_index=episode)
                with VideoWriter(video_path, plan.width, plan.height, FPS, plan.settings.codec) as writer:
                    for image in images:
                        writer.add(image)
                files += [data_path, video_path]
            records.append(record)
            next_index += count
            if report is not None:
                try:  # progress never fails an export
                    report(shard.record.first, shard.record.end, len(records), next_index - first_index)
                except Exception:
                    pass
        if video is not None:
            video.finish()
            video = None
            data_path = out / V30_DATA_PATH.format(chunk_index=chunk, file_index=file_index)
            _write_parquet(data_path, schema, data_tables)
            files += [data_path, out / V30_VIDEO_PATH.format(video_key=VIDEO_KEY, chunk_index=chunk, file_index=file_index)]
    finally:
        if video is not None:
            video.__exit__(RuntimeError, None, None)
    return records, files
