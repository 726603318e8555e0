"""The finished episodes of a shard still being written, kept so an interrupted run need
not compute them again.

A :class:`~catalog.tables.shard.ShardWriter` keeps a shard's rows in temporary files that
only its ``finish`` completes: a run stopped mid-shard (Ctrl-C, a kill, a lost worker)
loses every episode of it. While a shard is in flight, its task therefore also saves each
finished episode here, exactly as the writer received it (the recorded spec, every frame
array's bytes, dtype and shape, the encoded images, and the caller's JSON ``info``: an eval
episode's status and counts), in ``<output>/.partial/<first>-<end>/<index>.episode``:

- one file per episode, written under a temporary name and renamed (no fsync: a file a
  crash damaged fails its checksum and its episode is computed again);
- the file is ``MAGIC`` + the sha256 of its body + the body, an Arrow IPC stream (a table of
  named binary blobs, the spec, the info and the job key in its schema metadata);
- the job key (:attr:`PartialShard.job_key`) names the job whose episode it is (its
  identity, settings and dataset version, the code and library versions that write its
  bytes); :meth:`PartialShard.load` takes an episode only when the file's checksum holds and
  it was saved under this job key for this very spec, and deletes any other file of that
  name (another job's, a damaged one): its episode is then computed again, never mixed in.

The shard's task removes its folder once the shard's files are in place; the job removes
``.partial`` when it finishes or starts over (``--overwrite``). Nothing here is listed in a
manifest or read by ``catalog verify``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from catalog.store import atomic
from schemas.errors import SpecError
from schemas.frames import EpisodeFrames
from schemas.names import shorten
from schemas.spec import EpisodeSpec

#: The staging folder inside a job's output folder (hidden: no reader looks in it).
PARTIAL_DIR = ".partial"
MAGIC = b"DYANA-PARTIAL-EPISODE-1\n"
SUFFIX = ".episode"
#: The largest staged file read back (an episode of 224 px frames is a few MB): a bigger one,
#: planted or damaged, is deleted unread rather than allocated.
MAX_STAGED_BYTES = 256 << 20
_DIGEST = 32
_FRAME_FIELDS = tuple(f.name for f in dataclasses.fields(EpisodeFrames))
_SCHEMA = pa.schema([("name", pa.string()), ("dtype", pa.string()), ("shape", pa.string()), ("data", pa.large_binary())])
#: Array kinds a staged file may hold (bool, integers, floats): never Python objects.
_KINDS = "biuf"
_IMAGE = "image"


@dataclass(frozen=True)
class StagedEpisode:
    """An episode as it was given to the shard writer: the recorded spec, frames, encoded
    images, and the caller's ``info`` (JSON values)."""

    spec: EpisodeSpec
    frames: EpisodeFrames
    images: list[bytes]
    info: dict[str, Any] = field(default_factory=dict)


def remove_partial(folder: str | os.PathLike[str]) -> None:
    """Remove the staging folder of a job's output ``folder`` (finished, or started over)."""
    shutil.rmtree(Path(folder) / PARTIAL_DIR, ignore_errors=True)


@dataclass(frozen=True)
class PartialShard:
    """The staged episodes of shard ``[first, end)`` of the job ``job_key`` under ``root``
    (the job's output folder, shared by every worker that writes there)."""

    root: Path
    first: int
    end: int
    job_key: str

    def __post_init__(self) -> None:
        if not isinstance(self.root, Path):
            raise SpecError(f"PartialShard: root must be a Path, got {shorten(repr(self.root))}")
        ints = (self.first, self.end)
        if any(isinstance(v, bool) or not isinstance(v, int) for v in ints) or not 0 <= self.first < self.end:
            raise SpecError(f"PartialShard: episodes must be a range [first, end) with 0 <= first < end, got {ints!r}")
        if not isinstance(self.job_key, str) or not self.job_key:
            raise SpecError(f"PartialShard: job_key must be a non-empty str, got {shorten(repr(self.job_key))}")

    @property
    def folder(self) -> Path:
        """This shard's staging folder."""
        return self.root / PARTIAL_DIR / f"{self.first:06d}-{self.end:06d}"

    def path(self, index: int) -> Path:
        """The staged file of episode ``index``."""
        return self.folder / f"{index:06d}{SUFFIX}"

    def key(self, spec: EpisodeSpec) -> str:
        """What a staged file of ``spec`` must have been saved under: the job and the spec."""
        return hashlib.sha256(f"{self.job_key}\n{spec.to_json()}".encode()).hexdigest()

    def save(self, spec: EpisodeSpec, recorded: StagedEpisode) -> None:
        """Stage the episode of ``spec`` (the task's spec: the key) as ``recorded`` (what the
        writer was given). Best effort: a file that cannot be written is left out (its
        episode is computed again if the run is interrupted), never failing the shard."""
        body = _encode(self.key(spec), recorded)
        path = self.path(spec.episode_index)
        temp = atomic.temp_path(path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(temp, "wb") as handle:
                handle.write(MAGIC + hashlib.sha256(body).digest())
                handle.write(body)
            os.replace(temp, path)
        except OSError:
            atomic.discard(temp)
            for folder in (path.parent, path.parent.parent):  # made for nothing (a full disk): not left behind
                try:
                    folder.rmdir()
                except OSError:  # not empty (episodes staged before), or gone
                    break

    def load(self, spec: EpisodeSpec) -> StagedEpisode | None:
        """The staged episode of ``spec``, or None: none staged, or the file is refused
        (damaged, another job's or another spec's: then deleted)."""
        path = self.path(spec.episode_index)
        try:
            if path.stat().st_size > MAX_STAGED_BYTES:
                atomic.discard(path)
                return None
            data = path.read_bytes()
        except OSError:
            return None
        staged = _decode(data, self.key(spec))
        if staged is None:
            atomic.discard(path)
        return staged

    def remove(self) -> None:
        """Remove this shard's staging folder (its files are in place)."""
        shutil.rmtree(self.folder, ignore_errors=True)


def _encode(key: str, episode: StagedEpisode) -> bytes:
    names: list[str] = []
    dtypes: list[str] = []
    shapes: list[str] = []
    blobs: list[bytes] = []
    for name in _FRAME_FIELDS:
        value = getattr(episode.frames, name)
        if value is None:
            continue
        array = np.ascontiguousarray(value)
        names.append(name)
        dtypes.append(array.dtype.str)
        shapes.append(json.dumps(list(array.shape)))
        blobs.append(array.tobytes())
    for image in episode.images:
        names.append(_IMAGE)
        dtypes.append("")
        shapes.append("")
        blobs.append(bytes(image))
    metadata = {"key": key, "spec": episode.spec.to_json(), "info": json.dumps(episode.info, sort_keys=True)}
    table = pa.table([names, dtypes, shapes, blobs], schema=_SCHEMA.with_metadata(metadata))
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, table.schema) as writer:
        writer.write_table(table)
    return sink.getvalue().to_pybytes()


def _decode(data: bytes, key: str) -> StagedEpisode | None:
    """The episode in a staged file's bytes, or None unless its checksum holds and it was
    saved under ``key``."""
    head = len(MAGIC) + _DIGEST
    if not data.startswith(MAGIC) or len(data) < head:
        return None
    body = data[head:]
    if hashlib.sha256(body).digest() != data[len(MAGIC):head]:
        return None
    try:
        table = pa.ipc.open_stream(pa.py_buffer(body)).read_all()
        metadata = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}
        if metadata.get("key") != key or table.schema.remove_metadata() != _SCHEMA:
            return None
        columns = [table.column(name).to_pylist() for name in ("name", "dtype", "shape", "data")]
        arrays, images = _arrays(*columns)
        info = json.loads(metadata["info"])
        spec = EpisodeSpec.from_json(metadata["spec"])
        if not isinstance(info, dict) or set(arrays) - set(_FRAME_FIELDS):
            return None
        return StagedEpisode(spec, EpisodeFrames(**arrays), images, info)
    except (pa.ArrowException, ValueError, TypeError, KeyError, UnicodeDecodeError, SpecError):
        return None


def _arrays(names: Sequence[str], dtypes: Sequence[str], shapes: Sequence[str],
            blobs: Sequence[bytes]) -> tuple[Mapping[str, np.ndarray], list[bytes]]:
    """The frame arrays (by field) and the images of a staged table's columns."""
    arrays: dict[str, np.ndarray] = {}
    images: list[bytes] = []
    for name, dtype_text, shape_text, blob in zip(names, dtypes, shapes, blobs, strict=True):
        if name == _IMAGE:
            images.append(blob)
            continue
        dtype = np.dtype(dtype_text)
        if dtype.kind not in _KINDS or name in arrays:
            raise ValueError(f"staged array {name!r}: {dtype_text!r}")
        shape = tuple(int(n) for n in json.loads(shape_text))
        arrays[name] = np.frombuffer(blob, dtype=dtype).reshape(shape).copy()
    return arrays, images
