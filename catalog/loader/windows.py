"""Index arithmetic of temporal windows: which frames of an episode a history or an
action horizon covers, and which of them are padding.

Everything is integer frame arithmetic on ``frame_index`` (0-based, ``n`` frames
per episode): a window never reads a timestamp and never leaves its episode.
Positions outside ``[0, n)`` are padding; they are clamped to the nearest frame of
the episode (the first for a history, the last for a horizon), so a padded slot
repeats a real value and its ``*_is_pad`` flag says it is not one.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence

import numpy as np


def window(frame: int, num_frames: int, start: int, length: int) -> tuple[np.ndarray, np.ndarray]:
    """Frames ``frame + start ... frame + start + length - 1`` of an ``num_frames``-frame episode.

    Returns (clamped frame indices int64 (length,), is_pad bool (length,)).
    """
    if not 0 <= frame < num_frames:
        raise IndexError(f"frame {frame} is outside an episode of {num_frames} frames")
    if length < 1:
        raise ValueError(f"a window needs length >= 1, got {length}")
    wanted = np.arange(frame + start, frame + start + length, dtype=np.int64)
    is_pad = (wanted < 0) | (wanted >= num_frames)
    return np.clip(wanted, 0, num_frames - 1), is_pad


def history_window(frame: int, num_frames: int, history: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``history`` frames before ``frame`` and ``frame`` itself, oldest first (length history + 1)."""
    return window(frame, num_frames, -history, history + 1)


def horizon_window(frame: int, num_frames: int, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """``frame`` and the ``horizon - 1`` frames after it (length horizon)."""
    return window(frame, num_frames, 0, horizon)


def history_span(frame: int, history: int) -> tuple[int, int]:
    """(padded slots, first real frame) of :func:`history_window`: the window is ``pad``
    copies of frame 0 followed by frames ``start ... frame``. Plain integers, for the
    dataloader's per-item path (no arrays made)."""
    start = frame - history
    return (-start, 0) if start < 0 else (0, start)


def horizon_span(frame: int, num_frames: int, horizon: int) -> tuple[int, int]:
    """(last real frame + 1, padded slots) of :func:`horizon_window`: the window is frames
    ``frame ... stop - 1`` followed by ``pad`` copies of frame ``num_frames - 1``."""
    stop = frame + horizon
    return (num_frames, stop - num_frames) if stop > num_frames else (stop, 0)


def episode_starts(lengths: Sequence[int]) -> list[int]:
    """Position of each episode's first frame when episodes of ``lengths`` frames are concatenated."""
    starts, total = [], 0
    for n in lengths:
        if n < 0:
            raise ValueError(f"an episode cannot have {n} frames")
        starts.append(total)
        total += int(n)
    return starts


def locate(position: int, starts: Sequence[int], total: int) -> tuple[int, int]:
    """(episode k, frame within it) of a position in the concatenation; ``starts`` from :func:`episode_starts`.

    Empty episodes (equal consecutive starts) are never returned.
    """
    if not 0 <= position < total:
        raise IndexError(f"frame {position} is out of range for {total} frames")
    k = bisect.bisect_right(starts, position) - 1
    return k, position - starts[k]
