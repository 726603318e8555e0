"""Built slices or evaluated runs as one LeRobot dataset: what an export is (the field
mapping is in :mod:`catalog.export.layout`).

An export has one or more sources (folders), their episodes renumbered in the order the
sources are given. Work is done shard by shard (a *unit*: the sources' shards numbered in
that order): in v3.0 a Dyana shard becomes one data file and one video file
(``file-<unit>``), in v2.1 one data and one video file per episode
(:mod:`catalog.export.unit`). A finished unit leaves a part record (its
episodes' metadata, statistics and files with their sha256) in ``OUT/.dyana-export/``;
when every unit is done the metadata is assembled (:mod:`catalog.export.meta`) and
``meta/dyana.json`` is written last: it lists every file with its sha256 and marks the
export finished. The same source and settings give the same bytes
(:mod:`catalog.export.video`); the codec build is recorded.

Running an export (the folder lock, resume, progress, "up to date") is the job engine's:
:mod:`pipeline.jobs.export` (``catalog export``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from catalog.export.layout import FORMATS
from catalog.export.video import CODECS, codec_versions
from catalog.store.records import FileRecord
from catalog.tables.reader import FolderReader
from schemas.errors import DyanaError
from schemas.names import shorten

WORK_DIR = ".dyana-export"
EXPORT_VERSION = 3

#: A JSON value read from or written to a part record or metadata file (checked where it is used).
Json = Any


class ExportError(DyanaError):
    """The export cannot be made into this folder, or its source cannot be read."""


@dataclass(frozen=True)
class ExportSettings:
    """What decides an export's bytes besides its sources: the format, the video codec, and
    whether the object's true pose is exported as ``observation.environment_state``."""

    format: str
    codec: str = "h264"
    environment_state: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.environment_state, bool):
            raise ExportError(f"environment_state must be True or False, got {shorten(repr(self.environment_state))}")
        if not isinstance(self.format, str) or self.format not in FORMATS:
            raise ExportError(f"--format {shorten(repr(self.format))}: expected one of {sorted(FORMATS)}")
        if not isinstance(self.codec, str) or self.codec not in CODECS:
            raise ExportError(f"--codec {shorten(repr(self.codec))}: expected one of {sorted(CODECS)}")

    @property
    def version(self) -> str:
        return FORMATS[self.format]


@dataclass(frozen=True)
class Unit:
    """One source shard of an export: its source (position in the plan's sources), the
    shard's first episode there, its first episode and frame in the export, and its
    episode and frame counts."""

    source: int
    source_first: int
    episode: int
    index: int
    episodes: int
    frames: int


@dataclass(frozen=True)
class ExportPlan:
    """Everything a unit's worker needs besides its shard: the source folders and their
    slice hashes, the output folder, the settings, the task index of each task text, the
    image size, and the units in export order."""

    sources: tuple[str, ...]
    hashes: tuple[str, ...]
    out: str
    settings: ExportSettings
    tasks: Mapping[str, int]
    height: int
    width: int
    units: tuple[Unit, ...]

    def __post_init__(self) -> None:
        if not self.sources or len(self.sources) != len(self.hashes):
            raise ExportError("an export plan needs one slice hash per source, and a source")

    def unit_at(self, episode: int) -> tuple[int, Unit]:
        """The number and unit whose first exported episode is ``episode``."""
        for number, unit in enumerate(self.units):
            if unit.episode == episode:
                return number, unit
        raise ExportError(f"no unit of this export starts at episode {episode}")


def json_int(value: Json) -> int:
    """An integer read from a part record (ExportError if it is not one)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ExportError(f"a part record holds {shorten(repr(value))} where an integer belongs")
    return value


def job_identity(readers: Sequence[FolderReader], settings: ExportSettings) -> dict[str, Json]:
    """What an export folder must hold to be this export (``meta/dyana.json``'s ``job``)."""
    return {
        "export_version": EXPORT_VERSION,
        "sources": [{"source_hash": r.manifest.hash, "slice": r.manifest.slice} for r in readers],
        "settings": asdict(settings),
        "codec": codec_versions(settings.codec),
    }


def part_path(out: Path, shard: int) -> Path:
    """Where a finished unit's part record lives."""
    return out / WORK_DIR / f"part-{shard:05d}.json"


@dataclass(frozen=True)
class Part:
    """A finished unit: source shard ``shard`` (episodes [first, end), ``frames`` frames),
    its episodes' metadata and statistics (``episodes``, JSON as written) and its files."""

    shard: int
    episodes: tuple[Mapping[str, Json], ...]
    files: tuple[FileRecord, ...]

    @property
    def first(self) -> int:
        return json_int(self.episodes[0]["episode_index"])

    @property
    def end(self) -> int:
        return json_int(self.episodes[-1]["episode_index"]) + 1

    @property
    def frames(self) -> int:
        return sum(json_int(e["length"]) for e in self.episodes)

    def to_dict(self) -> dict[str, Json]:
        return {
            "shard": self.shard,
            "episodes": [dict(e) for e in self.episodes],
            "files": {f.path: {"sha256": f.sha256, "size": f.size} for f in self.files},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Json]) -> Part:
        """A part record as written (ExportError naming what is wrong otherwise)."""
        try:
            episodes = data["episodes"]
            files = data["files"]
            shard = data["shard"]
            if not isinstance(episodes, list) or not episodes or not isinstance(files, dict) or not isinstance(shard, int):
                raise TypeError("episodes, files or shard")
            return cls(shard, tuple(episodes), tuple(FileRecord.from_dict({"path": p, **f}) for p, f in files.items()))
        except (KeyError, TypeError, ValueError, DyanaError) as exc:
            raise ExportError(f"a part record is unreadable ({shorten(str(exc))})") from None


def read_part(out: Path, shard: int) -> Part | None:
    """The part record of unit ``shard``, or None when there is none or it is unreadable."""
    path = part_path(out, shard)
    if not path.is_file():
        return None
    try:
        return Part.from_dict(json.loads(path.read_text()))
    except (OSError, ValueError, ExportError):
        return None
