"""A motion cut into segments of one kind (straight, arc, harmonic, clothoid), stepped on a
fixed grid anchored at each segment's start; arc length."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from generators.tracks import (
    _GL3_W,
    _GL3_X,
    ROLL_STEP_S,
    _check_motion,
    _compile,
    _evaluate,
    _Piece,
    _times,
    _weighted,
)
from schemas.motion import (
    Motion,
)

# ------------------------------------------------------------------------- segments


@dataclass(frozen=True)
class _Segment:
    """A stretch of time on which one analytic description of the velocity holds.

    ``line``: velocity along the fixed direction ``u`` (``still`` if it is zero);
    ``arc``: constant ``speed`` with heading ``heading + rate (t - t0)``;
    ``general``: anything else (clothoids, drifting harmonics, active overlays).
    """

    t0: float
    t1: float
    kind: str
    piece: _Piece | None = None
    still: bool = False
    u: tuple[float, float] = (1.0, 0.0)
    heading: float = 0.0
    speed: float = 0.0
    rate: float = 0.0


def _classify(piece: _Piece, t0: float, t1: float) -> _Segment:
    p, tau = piece.p, t0 - piece.t0
    if piece.kind == "L":
        return _Segment(t0, t1, "line", piece, p[4] == 0.0 and p[5] == 0.0, (p[2], p[3]))
    if piece.kind == "H":
        if p[7] == 0.0 and p[8] == 0.0:
            return _Segment(t0, t1, "line", piece, p[4] == 0.0, (p[2], p[3]))
        return _Segment(t0, t1, "general", piece)
    if piece.kind == "A":
        cx, cz, radius, w, th0, turn = p
        if w == 0.0:
            h = th0 + turn * math.pi / 2.0
            return _Segment(t0, t1, "line", piece, True, (math.cos(h), math.sin(h)))
        heading = th0 + w * tau + math.copysign(math.pi / 2.0, w)
        return _Segment(t0, t1, "arc", piece, heading=heading, speed=radius * abs(w), rate=w)
    sx, sz, h0, speed, k0, c = p
    if speed == 0.0:
        return _Segment(t0, t1, "line", piece, True, (math.cos(h0), math.sin(h0)))
    if c != 0.0:
        return _Segment(t0, t1, "general", piece)
    heading = h0 + k0 * speed * tau
    if k0 == 0.0:
        return _Segment(t0, t1, "line", piece, False, (math.cos(heading), math.sin(heading)))
    return _Segment(t0, t1, "arc", piece, heading=heading, speed=speed, rate=speed * k0)


@lru_cache(maxsize=256)
def _segments(motion: Motion) -> tuple[_Segment, ...]:
    base = _compile(motion.base)
    overlays = [_compile(o) for o in motion.overlays]
    cuts = {p.t0 for p in base.pieces[1:]}
    for comp in overlays:
        cuts.update(p.t0 for p in comp.pieces)
        cuts.add(comp.end)
    edges = [0.0] + sorted(c for c in cuts if c > 0.0) + [math.inf]
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        if any(comp.start <= a < comp.end for comp in overlays):
            out.append(_Segment(a, b, "general"))
            continue
        k = max(int(np.searchsorted(base.starts, a, side="right")) - 1, 0)
        out.append(_classify(base.pieces[k], a, b))
    return tuple(out)


def _walk(motion: Motion, t: np.ndarray, handler, state, width: int) -> np.ndarray:
    """Run ``handler(segment, times, state) -> (values, end_state)`` over the segments in
    time order, carrying the state across joins; ``values`` has one row per time."""
    segs = _segments(motion)
    out = np.empty((t.shape[0], width))
    if not t.size:
        return out
    idx = np.searchsorted(np.array([s.t0 for s in segs]), t, side="right") - 1
    last = int(idx.max())
    for i in range(last + 1):
        mask = idx == i
        times = t[mask]
        n = times.shape[0]
        if i < last:
            times = np.append(times, segs[i + 1].t0)
        values, end = handler(segs[i], times, state)
        out[mask] = values[:n]
        state = end
    return out


def _grid(seg: _Segment, times: np.ndarray) -> tuple[np.ndarray, int]:
    """Index of the grid node at or before each time, and the number of full steps."""
    k = np.maximum(np.floor((times - seg.t0) / ROLL_STEP_S).astype(np.int64), 0)
    return k, int(k.max()) if k.size else 0


def _gauss(a: np.ndarray, h: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Times ``a + h * x`` for each quadrature node ``x``, shape ``(len(a), len(nodes))``."""
    return a[:, None] + h[:, None] * nodes[None, :]




def _along(d: np.ndarray, u) -> np.ndarray:
    """Row-wise dot products of (n, 2) vectors with the direction ``u``."""
    return d[:, 0] * u[0] + d[:, 1] * u[1]


def _speed_at(motion: Motion, times: np.ndarray) -> np.ndarray:
    v = _evaluate(motion, times.reshape(-1)).velocity
    return np.hypot(v[:, 0], v[:, 1]).reshape(times.shape)


# ----------------------------------------------------------------------- arc length


def _piece_distance(piece: _Piece, tau: np.ndarray) -> np.ndarray:
    """Closed-form distance travelled since the piece's start (not for drifting H
    or curving clothoids, which are ``general`` segments)."""
    p = piece.p
    if piece.kind == "L":
        v0, a = p[4], p[5]
        signed = tau * (v0 + 0.5 * a * tau)
        if a >= 0.0:
            return signed
        stop = v0 / -a
        peak = stop * (v0 + 0.5 * a * stop)
        return np.where(tau <= stop, signed, 2.0 * peak - signed)
    if piece.kind == "H":
        amp, om, ph = p[4], p[5], p[6]

        def folded(phi: np.ndarray) -> np.ndarray:  # antiderivative of |cos|
            m = np.floor((phi + math.pi / 2.0) / math.pi)
            return 2.0 * m + np.where(m % 2 == 0, 1.0, -1.0) * np.sin(phi)

        return amp * (folded(om * tau + ph) - folded(np.array([ph]))[0])
    if piece.kind == "A":
        return p[2] * abs(p[3]) * tau
    return p[3] * tau


def arc_length(motion: Motion, t) -> np.ndarray:
    """Distance travelled on [0, t], ``(n,)``: closed form for L, A, undrifted H and
    constant-curvature C; fixed-grid 3-point Gauss-Legendre quadrature (6th order on
    :data:`ROLL_STEP_S` steps) for curving clothoids, drifting harmonics and overlays."""
    _check_motion(motion)
    t = _times(t)

    def handler(seg: _Segment, times: np.ndarray, start: float):
        if seg.kind != "general":
            piece = seg.piece
            d = _piece_distance(piece, times - piece.t0) - _piece_distance(piece, np.array([seg.t0 - piece.t0]))[0]
            vals = start + d
            return vals[:, None], float(vals[-1])
        k, steps = _grid(seg, times)
        a = seg.t0 + ROLL_STEP_S * np.arange(steps)
        full = _weighted(_speed_at(motion, _gauss(a, np.full(steps, ROLL_STEP_S), _GL3_X)), _GL3_W) * ROLL_STEP_S
        nodes = start + np.concatenate([[0.0], np.cumsum(full)])
        ak = seg.t0 + ROLL_STEP_S * k
        part = _weighted(_speed_at(motion, _gauss(ak, times - ak, _GL3_X)), _GL3_W) * (times - ak)
        vals = nodes[k] + part
        return vals[:, None], float(vals[-1])

    return _walk(motion, t, handler, 0.0, 1)[:, 0]
