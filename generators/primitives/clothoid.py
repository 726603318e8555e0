"""``C``: a clothoid connector, curvature k0 + c s changing linearly with arc length s at
constant speed; after another token it inherits that token's end position, heading,
speed and curvature (a G2 join).

Piece parameters ``p = (sx, sz, h0, V, k0, c)``: the start, heading, speed, curvature and
curvature slope. Positions are Fresnel integrals, or Gauss-Legendre quadrature where
that form is ill-conditioned.
"""

from __future__ import annotations

import math

import numpy as np

from generators.primitives.base import XZ, Box, EndState, Piece, Primitive, Segment, register
from generators.quadrature import weighted_sum
from schemas.errors import SpecError
from schemas.limits import MAX_TURNING
from schemas.motion import ClothoidToken

_GL10_X, _GL10_W = np.polynomial.legendre.leggauss(10)
_GL10_X, _GL10_W = 0.5 * (_GL10_X + 1.0), 0.5 * _GL10_W
#: Absolute error budget (units) of the Fresnel form; beyond it clothoids use quadrature.
_FRESNEL_BUDGET = 1e-11


def clothoid_integral(h0: float, k0: float, c: float, s: np.ndarray) -> np.ndarray:
    """Complex ``int_0^s exp(i (h0 + k0 x + c x^2 / 2)) dx`` for arc lengths ``s >= 0``."""
    if c == 0.0:
        if k0 == 0.0:
            return s * complex(math.cos(h0), math.sin(h0))
        half = 0.5 * k0 * s
        return s * np.sinc(half / math.pi) * np.exp(1j * (h0 + half))
    lam = math.sqrt(math.pi / abs(c))
    w0 = k0 / (c * lam)
    w1 = w0 + s / lam
    smax = float(s.max()) if s.size else 0.0
    wmax = max(abs(w0), abs(w0 + smax / lam))
    if 2.2e-16 * (lam * (1.0 + wmax) + smax * wmax * wmax) > _FRESNEL_BUDGET:
        return clothoid_quadrature(h0, k0, c, s)
    # imported here: scipy.special costs ~0.7 CPU s to import (every `pipeline`, `catalog`
    # and `scoring` process and Dask worker imports this module; only clothoids call it)
    from scipy.special import fresnel

    s1, c1 = fresnel(w1)
    s0, c0 = fresnel(w0)
    sign = 1.0 if c > 0 else -1.0
    phase = h0 - k0 * k0 / (2.0 * c)
    return lam * complex(math.cos(phase), math.sin(phase)) * ((c1 - c0) + 1j * sign * (s1 - s0))


def clothoid_quadrature(h0: float, k0: float, c: float, s: np.ndarray) -> np.ndarray:
    """Composite 10-point Gauss-Legendre with at most 0.5 rad of turning per panel
    (error near machine precision); used where the Fresnel form is ill-conditioned
    (a slope tiny against the squared initial curvature)."""
    smax = float(s.max()) if s.size else 0.0
    turning = (abs(k0) + abs(c) * smax) * smax
    panels = max(1, math.ceil(turning / 0.5))
    out = np.empty(s.shape, dtype=np.complex128)
    j = np.arange(panels, dtype=np.float64)[:, None]
    frac = ((j + _GL10_X[None, :]) / panels).ravel()
    weights = np.tile(_GL10_W, panels) / panels
    for lo in range(0, s.size, 256):
        chunk = s[lo : lo + 256]
        x = chunk[:, None] * frac[None, :]
        out[lo : lo + 256] = weighted_sum(np.exp(1j * (k0 * x + 0.5 * c * x * x)), weights) * chunk
    return out * complex(math.cos(h0), math.sin(h0))


def _extreme_lengths(h0: float, k0: float, c: float, length: float) -> list[float]:
    """Arc lengths in [0, length] where the heading is a multiple of pi/2 (x or z extreme)."""
    ends = [h0, h0 + length * (k0 + 0.5 * c * length)]
    if c != 0.0 and 0.0 < -k0 / c < length:
        ends.append(h0 - k0 * k0 / (2.0 * c))
    lo, hi = min(ends), max(ends)
    out = [0.0, length]
    m = math.ceil(lo / (math.pi / 2.0))
    while m * math.pi / 2.0 <= hi:
        target = m * math.pi / 2.0
        if c == 0.0:
            if k0 != 0.0:
                out.append((target - h0) / k0)
        else:
            disc = k0 * k0 - 2.0 * c * (h0 - target)
            if disc >= 0.0:
                r = math.sqrt(disc)
                q = -0.5 * (k0 + math.copysign(r, k0)) if k0 != 0.0 else -0.5 * r
                if q != 0.0:
                    out.append(2.0 * q / c)  # the two roots of (c/2) s^2 + k0 s + (h0 - target)
                    out.append((h0 - target) / q)
                else:
                    out.append(0.0)
        m += 1
    return [s for s in out if 0.0 <= s <= length]


@register(ClothoidToken)
class Clothoid(Primitive[ClothoidToken]):
    """``C`` tokens; after another token only ``curvature_slope`` and ``duration`` are its own."""

    def place(self, token: ClothoidToken, t0: float, prev: EndState | None) -> Piece:
        if prev is None:
            p = (*token.start, token.heading, token.speed, token.curvature, token.curvature_slope)
        else:
            pos, heading, speed, kappa = prev
            p = (float(pos[0]), float(pos[1]), heading, speed, kappa, token.curvature_slope)
        # the token checked its own speed and curvature; joined, it inherits others, and its
        # quadrature's panels grow with the turning
        length = p[3] * token.duration
        turning = (abs(p[4]) + abs(p[5]) * length) * length
        if not turning <= MAX_TURNING:
            raise SpecError(
                f"a C token starting at {t0:.3f} s, joined at {p[3]:.4g} units/s and curvature {p[4]:.4g}, turns "
                f"the heading by up to {turning:.4g} rad (at most {MAX_TURNING:.4g}: 32 turns)"
            )
        return Piece(self, t0, token.duration, p)

    def evaluate(self, piece: Piece, tau: np.ndarray) -> XZ:
        n = tau.shape[0]
        pos, vel, acc = np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2))
        sx, sz, h0, speed, k0, c = piece.p
        s = speed * tau
        th = h0 + s * (k0 + 0.5 * c * s)
        integral = clothoid_integral(h0, k0, c, s)
        pos[:, 0], pos[:, 1] = sx + integral.real, sz + integral.imag
        cs, sn = np.cos(th), np.sin(th)
        vel[:, 0], vel[:, 1] = speed * cs, speed * sn
        kv2 = (k0 + c * s) * speed * speed
        acc[:, 0], acc[:, 1] = -kv2 * sn, kv2 * cs
        return pos, vel, acc

    def natural_heading(self, piece: Piece, tau: float) -> float:
        p = piece.p
        s = p[3] * tau
        return p[2] + s * (p[4] + 0.5 * p[5] * s)

    def segment(self, piece: Piece, t0: float, t1: float) -> Segment:
        sx, sz, h0, speed, k0, c = piece.p
        if speed == 0.0:
            return Segment(t0, t1, "line", piece, True, (math.cos(h0), math.sin(h0)))
        if c != 0.0:
            return Segment(t0, t1, "general", piece)
        heading = h0 + k0 * speed * (t0 - piece.t0)
        if k0 == 0.0:
            return Segment(t0, t1, "line", piece, False, (math.cos(heading), math.sin(heading)))
        return Segment(t0, t1, "arc", piece, heading=heading, speed=speed, rate=speed * k0)

    def distance(self, piece: Piece, tau: np.ndarray) -> np.ndarray:
        return piece.p[3] * tau

    def bounds(self, piece: Piece, span: float) -> Box:
        sx, sz, h0, speed, k0, c = piece.p
        s = np.array(_extreme_lengths(h0, k0, c, speed * span))
        z = clothoid_integral(h0, k0, c, s)
        return sx + float(z.real.min()), sx + float(z.real.max()), sz + float(z.imag.min()), sz + float(z.imag.max())
