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

import cv2
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
        """Per-channel moments of uint8 RGB frames (n, H, W, 3) scaled to [0, 1]; count = frames.

        Exact, from each channel's 256-bin histogram (``cv2.calcHist``, counted in batches
        small enough for its float32 bins to stay exact, summed as integers).
        """
        n, height, width, _ = frames.shape
        counts = np.zeros((3, 256), dtype=np.int64)
        batch = max(1, (1 << 23) // (height * width))
        for start in range(0, n, batch):
            image = np.ascontiguousarray(frames[start : start + batch]).reshape(-1, width, 3)
            for c in range(3):
                counts[c] += cv2.calcHist([image], [c], None, [256], [0, 256]).reshape(-1).astype(np.int64)
        values = np.arange(256, dtype=np.float64) / 255.0
        pixels = counts.sum(axis=1).astype(np.float64)
        mean = counts @ values / pixels
        m2 = counts @ (values * values) - pixels * mean * mean
        present = counts > 0
        low = values[np.argmax(present, axis=1)]
        high = values[255 - np.argmax(present[:, ::-1], axis=1)]
        shape = (3, 1, 1)
        # m2 over pixels, scaled to frames: merging by frame counts then stays exact
        per_frame = height * width
        return cls(n, mean.reshape(shape), (np.maximum(m2, 0.0) / per_frame).reshape(shape),
                   low.reshape(shape), high.reshape(shape))

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
