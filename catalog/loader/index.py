"""The dataloader's index: which episodes an opened dataset holds and where their frames are.

Built once at open from the manifests, the episodes tables and the ``episode_index`` /
``frame_index`` columns (read and checked through :mod:`catalog.tables.reader`); the float
columns' layout in a loaded shard's matrix is defined here too.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from catalog.store.storage import is_remote
from catalog.tables.parquet_io import column_to_numpy
from catalog.tables.reader import check_file, open_folder
from schemas.errors import SpecError
from schemas.names import shorten
from schemas.tables import ARRAY_WIDTHS, STATE_COLUMNS

VERIFY_MODES = ("sha256", "checksums")
#: Float columns of an item, in frames-table order; a shard keeps them side by side in one
#: float32 matrix (``fingertip_distance``, a scalar, takes one column).
FLOAT_COLUMNS = (*STATE_COLUMNS, "action", "fingertip_distance")


def float_layout() -> dict[str, tuple[int, int]]:
    layout, start = {}, 0
    for name in FLOAT_COLUMNS:
        width = ARRAY_WIDTHS.get(name, 1)
        layout[name] = (start, start + width)
        start += width
    return layout


LAYOUT = float_layout()
FLOAT_WIDTH = LAYOUT[FLOAT_COLUMNS[-1]][1]
STATE_SLICES = tuple((name, slice(*LAYOUT[name])) for name in STATE_COLUMNS)
ACTION_SLICE = slice(*LAYOUT["action"])
DISTANCE_COLUMN = LAYOUT["fingertip_distance"][0]
SHARD_COLUMNS = ("episode_index", "frame_index", "timestamp", "phase", *FLOAT_COLUMNS)
EPISODE_COLUMNS = (
    "episode_index", "episode_id", "slice", "motion_type", "object", "hand",
    "rollout_format", "intercept_setting", "num_frames", "text", "observe_frames",
)


@dataclass(frozen=True)
class Episode:
    """One episode of an opened dataset, from its folder's episodes table.

    ``num_frames`` is the number of frames stored (an evaluated rollout holds as many
    as its policy ran, not its spec's ``num_frames``); its first ``observe_frames`` are the
    observe window (the hand acts from there on); ``policy`` and ``status`` are set
    for rollouts only; ``source`` is the folder's position in the opened list.
    """

    source: int
    episode_index: int
    episode_id: str
    slice: str
    motion_type: str
    intercept_setting: str
    object: str
    hand: str
    rollout_format: str
    num_frames: int
    text: str
    observe_frames: int = 0
    policy: str | None = None
    status: str | None = None


@dataclass(frozen=True)
class ShardFile:
    """A frames file as the index knows it: where, how big, its digests."""

    path: str
    size: int
    sha256: str
    frames: int
    index_digest: str  # sha256 of its episode_index + frame_index columns, as read at open
    resolution: int  # side of its square images, as its folder's settings say
    #: The remote file as a UPath with the storage options it was opened with (key, secret,
    #: endpoint_url given in code), which ``path`` (text) cannot carry; None for a local file.
    location: Path | None = None


@dataclass(frozen=True)
class Options:
    history: int
    action_horizon: int | None
    resize: tuple[int, int] | None
    verify: str
    cache_bytes: int
    keys: str = "dyana"
    image_dtype: str = "float32"
    resample: str = "area"  # how ``resize`` resamples: catalog.loader.decode.RESAMPLE_MODES


def index_digest(episode: np.ndarray, frame: np.ndarray) -> str:
    digest = hashlib.sha256(np.ascontiguousarray(episode, dtype=np.int64).tobytes())
    digest.update(np.ascontiguousarray(frame, dtype=np.int32).tobytes())
    return digest.hexdigest()


def load_source(root: Path, source: int, verify: str, files: list[ShardFile]):
    """Episodes and spans (shard key, first row, frames) of one folder, read and checked
    through :func:`catalog.tables.reader.open_folder`; appends its frames files to ``files``.

    With ``verify="sha256"`` the small episodes files are hashed here and each frames
    file when its shard is first read (:class:`ShardCache`), not all of them up front."""
    folder = open_folder(root, verify="size")
    episodes: list[Episode] = []
    spans: list[tuple[int, int, int]] = []
    columns = list(EPISODE_COLUMNS) + (["policy", "status"] if folder.rollout else [])
    for shard in folder:
        if verify == "sha256":
            check_file(root, shard.record.files["episodes"], "sha256")
        table = shard.episodes(columns)
        index, runs = shard.indexed_frames([], table)
        episode = column_to_numpy(index.column("episode_index"))
        frame = column_to_numpy(index.column("frame_index"))
        frames_path = shard.path("frames")
        record = shard.record.files["frames"]
        key = len(files)
        files.append(
            ShardFile(
                str(frames_path), record.size, record.sha256, shard.record.frames, index_digest(episode, frame),
                folder.manifest.settings["resolution"], frames_path if is_remote(frames_path) else None,
            )
        )
        values = table.to_pydict()
        for row, episode_index in enumerate(values["episode_index"]):
            start, count = runs.get(episode_index, (0, 0))
            fields = {name: values[name][row] for name in columns}
            fields["num_frames"] = count
            episodes.append(Episode(source=source, **fields))
            spans.append((key, start, count))
    return folder.manifest, episodes, spans

def non_negative(name: str, value: Any, minimum: int, maximum: int | None = None) -> int:
    """``value`` as an int in [minimum, maximum]; SpecError naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise SpecError(f"{name} must be an integer >= {minimum}, got {shorten(repr(value))}")
    if maximum is not None and value > maximum:
        raise SpecError(f"{name} must be at most {maximum}, got {shorten(repr(value))}")
    return int(value)

