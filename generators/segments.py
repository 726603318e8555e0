"""A motion cut into segments of one kind (straight, arc, general), stepped on a fixed
grid anchored at each segment's start; arc length."""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from generators.primitives import Segment
from generators.quadrature import GL3_NODES, GL3_WEIGHTS, node_times, weighted_sum
from generators.tracks import ROLL_STEP_S, as_times, check_motion, compile_track, sample_motion
from schemas.motion import Motion

State = TypeVar("State")
#: ``handler(segment, times, state) -> (values, end_state)``, see :func:`walk`.
Handler = Callable[[Segment, np.ndarray, State], tuple[np.ndarray, State]]

# ------------------------------------------------------------------------- segments


@lru_cache(maxsize=256)
def segments(motion: Motion) -> tuple[Segment, ...]:
    """The motion's segments in time order, cut at every token start and overlay edge;
    a stretch where an overlay is active is ``general``."""
    base = compile_track(motion.base)
    overlays = [compile_track(o) for o in motion.overlays]
    cuts = {p.t0 for p in base.pieces[1:]}
    for comp in overlays:
        cuts.update(p.t0 for p in comp.pieces)
        cuts.add(comp.end)
    edges = [0.0] + sorted(c for c in cuts if c > 0.0) + [math.inf]
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        if any(comp.start <= a < comp.end for comp in overlays):
            out.append(Segment(a, b, "general"))
            continue
        piece = base.pieces[max(int(np.searchsorted(base.starts, a, side="right")) - 1, 0)]
        out.append(piece.primitive.segment(piece, a, b))
    return tuple(out)


def walk(motion: Motion, t: np.ndarray, handler: Handler[State], state: State, width: int) -> np.ndarray:
    """Run ``handler(segment, times, state) -> (values, end_state)`` over the segments in
    time order, carrying the state across joins; ``values`` has one row per time."""
    segs = segments(motion)
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


def grid_steps(seg: Segment, times: np.ndarray) -> tuple[np.ndarray, int]:
    """Index of the :data:`ROLL_STEP_S` grid node at or before each time, and the number of full steps."""
    k = np.maximum(np.floor((times - seg.t0) / ROLL_STEP_S).astype(np.int64), 0)
    return k, int(k.max()) if k.size else 0


def along(d: np.ndarray, u: tuple[float, float]) -> np.ndarray:
    """Row-wise dot products of (n, 2) vectors with the direction ``u``."""
    return d[:, 0] * u[0] + d[:, 1] * u[1]


def _speed_at(motion: Motion, times: np.ndarray) -> np.ndarray:
    v = sample_motion(motion, times.reshape(-1)).velocity
    return np.hypot(v[:, 0], v[:, 1]).reshape(times.shape)


# ----------------------------------------------------------------------- arc length


def arc_length(motion: Motion, t: npt.ArrayLike) -> np.ndarray:
    """Distance travelled on [0, t], ``(n,)``: closed form for L, A, undrifted H and
    constant-curvature C; fixed-grid 3-point Gauss-Legendre quadrature (6th order on
    :data:`ROLL_STEP_S` steps) for curving clothoids, drifting harmonics and overlays."""
    check_motion(motion)
    times_in = as_times(t)

    def handler(seg: Segment, times: np.ndarray, start: float) -> tuple[np.ndarray, float]:
        piece = seg.piece
        if seg.kind != "general" and piece is not None:
            primitive = piece.primitive
            d = primitive.distance(piece, times - piece.t0) - primitive.distance(piece, np.array([seg.t0 - piece.t0]))[0]
            vals = start + d
            return vals[:, None], float(vals[-1])
        k, steps = grid_steps(seg, times)
        a = seg.t0 + ROLL_STEP_S * np.arange(steps)
        full = weighted_sum(_speed_at(motion, node_times(a, np.full(steps, ROLL_STEP_S), GL3_NODES)), GL3_WEIGHTS) * ROLL_STEP_S
        nodes = start + np.concatenate([[0.0], np.cumsum(full)])
        ak = seg.t0 + ROLL_STEP_S * k
        part = weighted_sum(_speed_at(motion, node_times(ak, times - ak, GL3_NODES)), GL3_WEIGHTS) * (times - ak)
        vals = nodes[k] + part
        return vals[:, None], float(vals[-1])

    return walk(motion, times_in, handler, 0.0, 1)[:, 0]
