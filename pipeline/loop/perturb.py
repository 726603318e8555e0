"""Visually negligible perturbations of what a policy sees (paper A.5: a model should not
"produce unstable or divergent actions due to visually negligible background differences").

Each is a pure function of the decoded frame, a strength and a generator seeded from the
episode's spec hash, the repeat and the frame index (:func:`perturbation_rng`), so every
repeat of every episode is reproducible and repeats differ from each other. The recorded
frames stay the clean renders; the run's manifest records the protocol.

=========  ==================  ===============================================================
name       strength (default)  what changes
=========  ==================  ===============================================================
noise      2 (intensity)       independent integer noise uniform in [-s, s] on every channel
jpeg       75 (quality)        one more JPEG encode/decode (OpenCV, 4:2:0) at a quality drawn
                               per frame in [s - 5, s + 5] (a fixed quality would make every
                               repeat the same)
jitter     0.5 (pixels)        a sub-pixel shift of the whole image, each axis uniform in
                               [-s, s], bilinear, edges replicated (a camera tremor)
light      2 (percent)         every intensity scaled by 1 + u s/100, u uniform in [-1, 1]
=========  ==================  ===============================================================

Their PSNR against the clean frame is measured by ``benchmarks/perturbations.py``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from schemas.errors import SpecError
from schemas.names import shorten

#: Root of every perturbation seed (with the spec hash, the repeat and the frame).
PERTURB_SEED = 51_000
#: Half-width of the JPEG quality's per-frame range.
JPEG_SPREAD = 5.0


def _noise(image: np.ndarray, strength: float, rng: np.random.Generator) -> np.ndarray:
    s = int(round(strength))
    noise = rng.integers(-s, s + 1, size=image.shape, dtype=np.int16)
    return np.clip(image.astype(np.int16) + noise, 0, 255).astype(np.uint8)


def _jpeg(image: np.ndarray, strength: float, rng: np.random.Generator) -> np.ndarray:
    quality = int(np.clip(round(strength + JPEG_SPREAD * (2.0 * rng.random() - 1.0)), 1, 100))
    ok, data = cv2.imencode(".jpg", image[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise SpecError("JPEG re-encoding failed")
    decoded = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if decoded is None:
        raise SpecError("JPEG re-decoding failed")
    return np.ascontiguousarray(decoded[:, :, ::-1])


def _jitter(image: np.ndarray, strength: float, rng: np.random.Generator) -> np.ndarray:
    dx, dy = (strength * (2.0 * rng.random() - 1.0) for _ in range(2))
    shift = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    h, w = image.shape[:2]
    return cv2.warpAffine(image, shift, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _light(image: np.ndarray, strength: float, rng: np.random.Generator) -> np.ndarray:
    gain = 1.0 + (2.0 * rng.random() - 1.0) * strength / 100.0
    return np.clip(np.rint(image.astype(np.float32) * np.float32(gain)), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class _Kind:
    default: float
    low: float
    high: float
    apply: Callable[[np.ndarray, float, np.random.Generator], np.ndarray]


PERTURBATIONS: dict[str, _Kind] = {
    "noise": _Kind(2.0, 1.0, 16.0, _noise),
    "jpeg": _Kind(75.0, 30.0, 100.0, _jpeg),
    "jitter": _Kind(0.5, 0.05, 2.0, _jitter),
    "light": _Kind(2.0, 0.1, 10.0, _light),
}


@dataclass(frozen=True)
class Perturbation:
    """A named perturbation and its strength (the kind's default when None)."""

    name: str
    strength: float | None = None

    def __post_init__(self) -> None:
        if self.name not in PERTURBATIONS:
            raise SpecError(f"--perturb must be one of {sorted(PERTURBATIONS)}, got {shorten(repr(self.name))}")
        kind = PERTURBATIONS[self.name]
        value = kind.default if self.strength is None else self.strength
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SpecError(f"--perturb {self.name} strength must be a number, got {shorten(repr(value))}")
        if not kind.low <= value <= kind.high:
            raise SpecError(f"--perturb {self.name} strength must be in [{kind.low:g}, {kind.high:g}], got {shorten(repr(value))}")
        object.__setattr__(self, "strength", float(value))

    @classmethod
    def parse(cls, text: str) -> Perturbation:
        """``NAME`` or ``NAME:STRENGTH`` (the command line's form)."""
        name, colon, strength = str(text).partition(":")
        if not colon:
            return cls(name)
        if not strength.strip():
            raise SpecError(f"--perturb {shorten(repr(text))}: the strength after ':' is empty (give NAME or NAME:STRENGTH)")
        try:
            value = float(strength)
        except ValueError:
            raise SpecError(f"--perturb {shorten(repr(text))}: the strength must be a number") from None
        return cls(name, value)

    def apply(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The perturbed copy of an (H, W, 3) uint8 RGB frame."""
        assert self.strength is not None
        return PERTURBATIONS[self.name].apply(image, self.strength, rng)


def perturbation_rng(spec_hash: str, repeat: int, frame: int) -> np.random.Generator:
    """The generator of one frame's perturbation: from the episode (its spec hash), the
    repeat and the frame index only."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([PERTURB_SEED, int(spec_hash[:16], 16), repeat, frame])))


def psnr(clean: np.ndarray, other: np.ndarray) -> float:
    """Peak signal-to-noise ratio (dB) of ``other`` against ``clean`` (inf when equal)."""
    mse = float(np.mean((clean.astype(np.float64) - other.astype(np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0**2 / mse)
