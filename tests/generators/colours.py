"""Colour matching for rendered frames: shading scales a colour's RGB by the light."""

from __future__ import annotations

import numpy as np


def colour_mask(pixels, rgba, tol: float = 8.0) -> np.ndarray:
    """Which pixels (..., 3) are ``rgba`` under some lighting intensity in [0.5, 1.05]."""
    base = np.asarray(rgba[:3], dtype=np.float64) * 255.0
    px = np.asarray(pixels, dtype=np.float64)
    intensity = px @ base / (base @ base)
    off = np.abs(px - intensity[..., None] * base).max(axis=-1)
    return (intensity >= 0.5) & (intensity <= 1.05) & (off <= tol)


def matches(pixel, rgba, tol: float = 8.0) -> bool:
    return bool(colour_mask(pixel, rgba, tol))
