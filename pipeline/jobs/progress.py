"""Progress of a sharded job: what a shard task reports per episode, and the driver's lines.

A task is handed its reporter as an argument (:attr:`pipeline.jobs.tasks.ShardTask.report`,
or :class:`ReportingSpecs`); nothing is set process-wide. Reports carry only counts, go to
the terminal alone and never reach a file, and a failing reporter never fails a shard.
"""

from __future__ import annotations

import contextlib
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Protocol, TextIO

from schemas.cli import ProgressMeter
from schemas.spec import EpisodeSpec

#: ``(first, end, done, frames)``: ``done`` episodes (``frames`` frames) of the shard
#: [first, end) are finished.
EpisodeReport = Callable[[int, int, int, int], None]


class Unit(Protocol):
    """A finished unit of a job as progress counts it: episodes [first, end), frames."""

    @property
    def first(self) -> int: ...

    @property
    def end(self) -> int: ...

    @property
    def frames(self) -> int: ...


def to_stderr(line: str) -> None:
    """A progress line to the terminal (stderr), at once."""
    print(line, file=sys.stderr, flush=True)


def report_quietly(report: EpisodeReport | None, first: int, end: int, done: int, frames: int) -> None:
    """Call ``report`` if there is one; progress never fails the work it describes."""
    if report is not None:
        with contextlib.suppress(Exception):
            report(first, end, done, frames)


class ReportingSpecs(list[EpisodeSpec]):
    """A shard's specs (a plain list of EpisodeSpec) whose iteration calls ``report`` for
    each episode finished, when the next is asked for (its frames counted as the spec's
    ``num_frames``). Without a reporter it is just the list."""

    def __init__(self, specs: Sequence[EpisodeSpec], first: int, end: int, report: EpisodeReport | None = None) -> None:
        super().__init__(specs)
        self.first, self.end, self.report = first, end, report

    def __iter__(self) -> Iterator[EpisodeSpec]:
        if self.report is None:
            return super().__iter__()
        return self._reporting(self.report)

    def _reporting(self, report: EpisodeReport) -> Iterator[EpisodeSpec]:
        done = frames = 0
        for spec in super().__iter__():
            yield spec
            done += 1
            frames += int(spec.num_frames)
            report_quietly(report, self.first, self.end, done, frames)


class Progress:
    """The driver's progress lines: episodes done (per episode, as workers report them, and
    per finished shard), frames, frames/s and ETA, with the shards finished in front; the
    last line when every shard is finished. Frames of unfinished shards are counted as the
    tasks report them (a rollout that ends early has fewer: its shard's record corrects
    the count). Lines go to ``say`` if given, else to ``stream`` (default stderr)."""

    def __init__(self, total_shards: int, total_episodes: int, *, total_frames: int | None = None,
                 stream: TextIO | None = None, say: Callable[[str], None] | None = None) -> None:
        self.total_shards = total_shards
        self.meter = ProgressMeter(total_episodes, "episodes", total_frames=total_frames, stream=stream, say=say)
        self._lock = threading.Lock()
        self._running: dict[tuple[int, int], tuple[int, int]] = {}
        self._finished: dict[tuple[int, int], tuple[int, int]] = {}

    def _show(self) -> None:
        parts = [*self._running.values(), *self._finished.values()]
        self.meter.update(
            sum(p[0] for p in parts),
            sum(p[1] for p in parts),
            prefix=f"[{len(self._finished)}/{self.total_shards} shards]",
            last=len(self._finished) == self.total_shards,
        )

    def resumed(self, records: Sequence[Unit]) -> None:
        """Shards finished before this run: done, but not part of the rates."""
        with self._lock:
            for record in records:
                self._finished[(record.first, record.end)] = (record.end - record.first, record.frames)
            self.meter.resume(sum(p[0] for p in self._finished.values()), sum(p[1] for p in self._finished.values()))

    def episode(self, first: int, end: int, done: int, frames: int) -> None:
        """A worker's report: ``done`` episodes of shard [first, end) are finished."""
        with self._lock:
            key = (first, end)
            if key in self._finished or done <= self._running.get(key, (0, 0))[0]:
                return  # late or repeated
            self._running[key] = (done, frames)
            self._show()

    def update(self, record: Unit) -> None:
        """A shard finished: its episodes and (recorded) frames."""
        with self._lock:
            key = (record.first, record.end)
            self._running.pop(key, None)
            self._finished[key] = (record.end - record.first, record.frames)
            self._show()


def announcement(verb: str, slice_name: str, episodes: int, shard_size: int, resolution: int, counted: bool = True) -> str:
    """How big a job is, said before it starts: episodes, shards and, when ``counted``, the
    recipe's frames (:func:`generators.recipe.slice_summary`) and about how many bytes (the
    measured footprint, :mod:`catalog.store.footprint`)."""
    from catalog.store.footprint import footprint_at
    from generators.recipe import slice_summary

    shards = -(-episodes // shard_size)
    line = f"{verb} {slice_name}: {episodes:,} episodes"
    if counted:  # the recipe's count (a specs file's or a rollout's frames are their own)
        frames = int(slice_summary(slice_name, episodes)["total_frames"])
        line += f", {frames:,} frames"
    line += f", {shards:,} shard{'s' if shards != 1 else ''} of {shard_size}"
    size = None if not counted else footprint_at(slice_name, episodes, frames, resolution)
    if size is not None:
        line += f", about {_size(size.total)}"
    if shards > 1:
        line += "; Ctrl-C keeps finished shards, the same command resumes"
    return line


def _size(count: float) -> str:
    """A byte count as MB or GB, two significant figures."""
    return f"{count / 1e9:.2g} GB" if count >= 1e9 else f"{max(count / 1e6, 0.1):.2g} MB"
