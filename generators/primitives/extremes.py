"""Exact extremes of the trigonometric terms in the closed forms (for path bounds)."""

from __future__ import annotations

import math

TWO_PI = 2.0 * math.pi


def cos_range(lo: float, hi: float) -> tuple[float, float]:
    """Exact min and max of cos over [lo, hi]."""
    if hi - lo >= TWO_PI:
        return -1.0, 1.0
    values = [math.cos(lo), math.cos(hi)]
    k = math.ceil(lo / math.pi)
    while k * math.pi <= hi:
        values.append(1.0 if k % 2 == 0 else -1.0)
        k += 1
    return min(values), max(values)


def scaled_range(centre: float, scale: float, lo: float, hi: float) -> tuple[float, float]:
    """The range of ``centre + scale * x`` for x in [lo, hi]."""
    a, b = centre + scale * lo, centre + scale * hi
    return (a, b) if a <= b else (b, a)
