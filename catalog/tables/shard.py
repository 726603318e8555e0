"""ShardWriter: writes one shard (a fixed range of episodes) as its files.

The frames Parquet and the MCAP (unless ``settings.formats`` leaves it out) are streamed
episode by episode into temporary files beside their destinations; the episodes Parquet
is written at the end. Only :meth:`ShardWriter.finish` renames the temps to their final names (a shard
is complete once its files exist; the slice is complete once ``catalog.json`` lists
them). Any exception inside the ``with`` block, or a shard missing episodes,
deletes the temps: nothing half-written remains under a final name.

Usage::

    with ShardWriter(slice_dir, 0, 128, settings) as shard:
        for spec, frames, images in episodes:      # increasing episode_index
            shard.add_episode(spec, frames, images)
    record = shard.record                           # or: record = shard.finish()
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from catalog.store import atomic
from catalog.store.hashing import canonical_json, sha256_file
from catalog.store.records import REQUIRED_KINDS, FileRecord, ShardRecord, shard_paths
from catalog.tables.mcap_writer import McapShardWriter
from catalog.tables.parquet_io import (
    TableWriter,
    episode_row,
    episodes_table,
    frames_table,
    write_table,
)
from schemas.errors import ShardError, SpecError
from schemas.formats import stored_formats
from schemas.frames import EpisodeFrames
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

__all__ = ["FileRecord", "ShardRecord", "ShardWriter", "rollout_frame_limit"]

def rollout_frame_limit(spec: EpisodeSpec) -> int:
    """Most frames a rollout of ``spec`` records: the observe window plus the acting
    horizon ``spec.acting_horizon`` = ceil(1.2 x (num_frames - observe_frames))."""
    return spec.observe_frames + spec.acting_horizon


class ShardWriter:
    """Writes episodes ``[first_episode, last_episode_exclusive)`` of a slice folder.

    ``settings`` are the slice's settings (as in ``catalog.json``): ``fps`` (default 20)
    times the rows, ``image_format`` names the image encoding (``jpeg``, the only
    one the reader accepts) and ``resolution`` (square images) sets the MCAP camera calibration.
    ``rollout`` shards store the rollout episodes schema (``policy``, ``status``, ``error``).
    Every episode of the range must be added, in increasing order.
    """

    def __init__(
        self,
        root_dir: str | os.PathLike[str],
        first_episode: int,
        last_episode_exclusive: int,
        settings: Mapping[str, Any],
        rollout: bool = False,
    ) -> None:
        self.root = Path(root_dir)
        self.first, self.end = first_episode, last_episode_exclusive
        canonical_json(dict(settings))  # refuse settings that cannot go into the manifest
        self.settings = dict(settings)
        try:
            kinds = REQUIRED_KINDS + (("mcap",) if "mcap" in stored_formats(self.settings) else ())
        except SpecError as exc:
            raise ShardError(str(exc)) from None
        self.paths = {kind: path for kind, path in shard_paths(first_episode, last_episode_exclusive).items()
                      if kind in kinds}
        self.fps = self.settings.get("fps", FPS)
        self.rollout = rollout
        #: Frames carry the hand's obstacle clearance (a build whose scenes may hold obstacles).
        self.obstacles = bool(self.settings.get("obstacle_clearance", False))
        self._finals = {kind: self.root / rel for kind, rel in self.paths.items()}
        self._temps = {kind: atomic.temp_path(path) for kind, path in self._finals.items()}
        self._frames_writer: TableWriter | None = None
        self._mcap_stream: BinaryIO | None = None
        self._mcap: McapShardWriter | None = None
        self._rows: list[dict[str, Any]] = []
        self._next = first_episode
        self._frames = 0
        self._state = "new"  # new -> open -> finished | aborted (or failed, then aborted)
        self.record: ShardRecord | None = None

    # --- lifecycle ----------------------------------------------------------------------

    def start(self) -> ShardWriter:
        """Open the temporary files."""
        if self._state != "new":
            raise ShardError(f"shard {self.paths['frames']}: start() called twice")
        self._state = "open"
        try:
            for final in self._finals.values():
                final.parent.mkdir(parents=True, exist_ok=True)
            self._frames_writer = TableWriter(self._temps["frames"], "obstacle_frames" if self.obstacles else "frames")
            if "mcap" not in self._temps:
                return self
            self._mcap_stream = open(self._temps["mcap"], "wb")
            self._mcap = McapShardWriter(
                self._mcap_stream,
                first_episode=self.first,
                end_episode=self.end,
                settings=self.settings,
                rollout=self.rollout,
            )
        except BaseException:
            self.abort()
            raise
        return self

    def __enter__(self) -> ShardWriter:
        return self.start()

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            self.abort()
        elif self._state in ("open", "failed"):
            self.finish()

    def add_episode(
        self,
        spec: EpisodeSpec,
        frames: EpisodeFrames,
        images: Sequence[bytes],
        *,
        grasp_angles: np.ndarray | None = None,
        policy: str | None = None,
        status: str | None = None,
        error: str | None = None,
        privileged: bool = False,
    ) -> None:
        """Append one episode: its frames rows, MCAP messages and episodes row.

        ``grasp_angles`` defaults to ``frames.grasp_angles``. Rollout shards need
        ``policy`` and ``status`` (and ``error`` when status is ``error``) and accept
        1 to :func:`rollout_frame_limit` frames (a policy may take longer than the
        ground truth, or be cut short by an error).
        """
        where = self.paths["frames"]
        frames_writer = self._frames_writer  # set while the shard is open
        if self._state != "open" or frames_writer is None:
            raise ShardError(f"shard {where}: add_episode() on a writer that is {self._state}, not open")
        index = spec.episode_index
        if not self.first <= index < self.end:
            raise ShardError(f"shard {where}: episode {index} is outside [{self.first}, {self.end})")
        if index < self._next:
            raise ShardError(
                f"shard {where}: episode {index} added after episode {self._next - 1} (order must increase)"
            )
        n = frames.num_frames
        if self.rollout:
            limit = rollout_frame_limit(spec)
            if n > limit:
                raise ShardError(
                    f"episode {spec.episode_id}: {n} frames, more than a rollout's {limit} "
                    f"(observe_frames {spec.observe_frames} + horizon {limit - spec.observe_frames})"
                )
            if policy is None or status is None:
                raise ShardError(f"episode {spec.episode_id}: a rollout shard needs policy and status")
        else:
            if n != spec.num_frames:
                raise ShardError(f"episode {spec.episode_id}: {n} frames, the spec says {spec.num_frames}")
            if policy is not None or status is not None or error is not None:
                raise ShardError(f"episode {spec.episode_id}: policy/status/error belong to rollout shards only")
        angles = frames.grasp_angles if grasp_angles is None else grasp_angles
        row = episode_row(spec, angles, policy=policy, status=status, error=error, privileged=privileged)
        table = frames_table(index, frames, images, fps=self.fps, obstacles=self.obstacles)
        if self._mcap is not None:
            self._mcap.check_episode(index, frames, images)
        metadata = {"episode_id": spec.episode_id, "spec": spec.to_json()}
        if self.rollout:
            metadata.update(policy=row["policy"], status=row["status"], error=row["error"])
            if privileged:
                metadata["privileged"] = "true"
        try:
            if self._mcap is not None:
                self._mcap.add_episode(index, frames, images, metadata, spec.obstacles)
            frames_writer.write(table)
        except BaseException:
            self._state = "failed"
            raise
        self._rows.append(row)
        self._frames += n
        self._next = index + 1

    @property
    def result(self) -> ShardRecord:
        """The finished shard's record (after :meth:`finish` or leaving the ``with`` block)."""
        if self.record is None:
            raise ShardError(f"shard [{self.first}, {self.end}) is not finished")
        return self.record

    def finish(self) -> ShardRecord:
        """Complete the three files, rename them into place and return their record."""
        if self._state == "finished":
            return self.result
        if self._state != "open":
            state = self._state
            if state == "failed":  # a write failed mid-episode: its temps are incomplete, delete them
                self.abort()
                raise ShardError(
                    f"shard {self.paths['frames']}: an episode failed to write; the shard was discarded"
                )
            raise ShardError(f"shard {self.paths['frames']}: finish() on a writer that is {state}")
        committed: list[Path] = []
        try:
            added = [row["episode_index"] for row in self._rows]
            if added != list(range(self.first, self.end)):
                missing = sorted(set(range(self.first, self.end)) - set(added))
                shown = missing[:5] + (["..."] if len(missing) > 5 else [])
                raise ShardError(
                    f"shard {self.paths['frames']}: {len(missing)} episode(s) of [{self.first}, {self.end}) "
                    f"were not added: {shown}"
                )
            frames_writer, mcap, stream = self._frames_writer, self._mcap, self._mcap_stream
            if frames_writer is not None:  # set while the shard is open
                frames_writer.close()
            self._frames_writer = None
            if mcap is not None and stream is not None:
                mcap.close()
                stream.close()
            self._mcap, self._mcap_stream = None, None
            write_table(self._temps["episodes"], episodes_table(self._rows, self.rollout), self._kind)
            files = {}
            for kind, temp in self._temps.items():
                files[kind] = FileRecord(self.paths[kind], sha256_file(temp), temp.stat().st_size)
            for kind in self._temps:
                atomic.commit(self._temps[kind], self._finals[kind])
                committed.append(self._finals[kind])
        except BaseException:
            self.abort()
            for final in committed:  # a shard is all its files or none
                atomic.discard(final)
            raise
        self._state = "finished"
        self.record = ShardRecord((self.first, self.end), self._frames, files)
        return self.record

    def abort(self) -> None:
        """Close and delete the temporary files; nothing reaches a final name."""
        if self._state in ("finished", "aborted"):
            return
        self._state = "aborted"
        frames_writer, stream = self._frames_writer, self._mcap_stream
        self._frames_writer, self._mcap, self._mcap_stream = None, None, None
        try:
            for close in (frames_writer.abort if frames_writer else None, stream.close if stream else None):
                if close is not None:
                    with contextlib.suppress(OSError):  # a full disk fails the final flush; the file goes anyway
                        close()
        finally:
            for temp in self._temps.values():
                atomic.discard(temp)

    @property
    def _kind(self) -> str:
        return "rollout_episodes" if self.rollout else "episodes"

    @property
    def frames(self) -> int:
        """Frames added so far."""
        return self._frames
