"""LeRobot-style statistics: per episode (``meta/episodes_stats.jsonl``, ``stats/...``
columns) and merged over episodes (``meta/stats.json``).

Each feature gets ``min``, ``max``, ``mean``, ``std`` (population) and ``count`` (frames),
element by element in float64; images per channel, in [0, 1], shaped (3, 1, 1) as
LeRobot stores them. Merging uses the pairwise (Chan et al.) update, so the merged
numbers do not depend on how episodes were grouped.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Moments:
    """Statistics of one feature over some frames (arrays of the feature's shape)."""

    count: int
    mean: np.ndarray
    m2: np.ndarray  # sum of squared deviations from the mean
    min: np.ndarray
    max: np.ndarray

    @classmethod
    def of(cls, values: np.ndarray) -> Moments:
        """Moments over the first axis of ``values`` (frames, ...)."""
        x = np.asarray(values, dtype=np.float64)
        mean = x.mean(axis=0)
        return cls(len(x), mean, ((x - mean) ** 2).sum(axis=0), x.min(axis=0), x.max(axis=0))

    @classmethod
    def of_images(cls, frames: np.ndarray) -> Moments:
        """Per-channel moments of uint8 RGB frames (n, H, W, 3) scaled to [0, 1]; count = frames."""
        n = len(frames)
        pixels = frames.reshape(-1, 3)
        total = pixels.astype(np.float64).sum(axis=0)
        squares = np.einsum("ij,ij->j", pixels.astype(np.float64), pixels.astype(np.float64))
        per_frame = pixels.shape[0] // max(n, 1)
        mean = total / pixels.shape[0]
        m2 = squares - total * mean
        shape = (3, 1, 1)
        # m2 is over pixels; scale to frames so that merging by frame counts stays exact
        return cls(
            n,
            (mean / 255.0).reshape(shape),
            (np.maximum(m2, 0.0) / per_frame / 255.0**2).reshape(shape),
            (pixels.min(axis=0) / 255.0).reshape(shape),
            (pixels.max(axis=0) / 255.0).reshape(shape),
        )

    def merge(self, other: Moments) -> Moments:
        n = self.count + other.count
        delta = other.mean - self.mean
        mean = self.mean + delta * (other.count / n)
        m2 = self.m2 + other.m2 + delta * delta * (self.count * other.count / n)
        return Moments(n, mean, m2, np.minimum(self.min, other.min), np.maximum(self.max, other.max))

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(self.m2 / max(self.count, 1))

    def to_dict(self) -> dict[str, Any]:
        return {
            "min": self.min.tolist(),
            "max": self.max.tolist(),
            "mean": self.mean.tolist(),
            "std": self.std.tolist(),
            "count": [self.count],
        }

    def to_state(self) -> dict[str, Any]:
        """Exact serialisation (for resuming), :meth:`from_state` reverses it."""
        return {"count": self.count, "mean": self.mean.tolist(), "m2": self.m2.tolist(),
                "min": self.min.tolist(), "max": self.max.tolist()}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> Moments:
        return cls(int(state["count"]), *(np.asarray(state[k], dtype=np.float64) for k in ("mean", "m2", "min", "max")))


def merge_all(parts: list[Moments]) -> Moments:
    out = parts[0]
    for part in parts[1:]:
        out = out.merge(part)
    return out
