"""Motion tracks compiled into closed-form pieces: r(t), v(t), a(t) and curvature of a
motion at any times (the semantics are in :mod:`generators.motion`; each token's closed
forms are its primitive's, :mod:`generators.primitives`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache

import numpy as np
import numpy.typing as npt

from generators.primitives import EndState, Piece, primitive_for
from schemas.errors import SpecError
from schemas.motion import Motion, Token, Track

#: Speeds at or below this (units/s) count as standing still: no heading, zero curvature.
ZERO_SPEED = 1e-9
#: Substep of the fixed integration grid for path-dependent rolling quantities (s).
ROLL_STEP_S = 1.0 / 400.0


@dataclass(frozen=True)
class MotionSample:
    """Position, velocity and acceleration in the XZ plane, each ``(n, 2)`` float64."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


# ----------------------------------------------------------------------------- pieces


@dataclass(frozen=True)
class CompiledTrack:
    """A track's pieces on the global clock, their start times and the track's span."""

    pieces: tuple[Piece, ...]
    starts: np.ndarray
    start: float
    end: float
    origin: np.ndarray  # position at the track's start


def end_state(piece: Piece) -> EndState:
    """Position, heading, speed and signed curvature at the piece's end."""
    pos, vel, acc = (x[0] for x in piece.evaluate(np.array([piece.duration])))
    speed = math.hypot(vel[0], vel[1])
    if speed > ZERO_SPEED:
        heading = math.atan2(vel[1], vel[0])
        kappa = (vel[0] * acc[1] - vel[1] * acc[0]) / speed**3
    else:
        # v(tau) ~ a (tau - T) just before a stop: the motion came from -a.
        amag = math.hypot(acc[0], acc[1])
        heading = (math.atan2(-acc[1], -acc[0]) if amag > ZERO_SPEED
                   else piece.primitive.natural_heading(piece, piece.duration))
        kappa = 0.0
    return EndState(pos, heading, speed, kappa)


def place(token: Token, t0: float, prev: Piece | None) -> Piece:
    """``token`` as a piece starting at ``t0``, joined to the end of ``prev`` (None opens a track)."""
    return primitive_for(token).place(token, t0, end_state(prev) if prev is not None else None)


@lru_cache(maxsize=1024)
def compile_track(track: Track) -> CompiledTrack:
    """The track's tokens placed one after another (cached: tracks are immutable)."""
    pieces: list[Piece] = []
    elapsed = Fraction(0)  # exact, so each start is the correctly rounded prefix sum (as math.fsum gives) in linear time
    for token in track.tokens:
        t0 = track.start + float(elapsed)
        pieces.append(place(token, t0, pieces[-1] if pieces else None))
        elapsed += Fraction(token.duration)
    origin = pieces[0].evaluate(np.zeros(1))[0][0]
    starts = np.array([p.t0 for p in pieces])
    return CompiledTrack(tuple(pieces), starts, track.start, track.end, origin)


def _eval_track(comp: CompiledTrack, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if len(comp.pieces) == 1:
        piece = comp.pieces[0]
        return piece.evaluate(t - piece.t0)
    idx = np.maximum(np.searchsorted(comp.starts, t, side="right") - 1, 0)
    n = t.shape[0]
    pos, vel, acc = np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2))
    for k in np.unique(idx):
        mask = idx == k
        piece = comp.pieces[k]
        pos[mask], vel[mask], acc[mask] = piece.evaluate(t[mask] - piece.t0)
    return pos, vel, acc


def check_motion(motion: object) -> Motion:
    """``motion`` itself, or :class:`SpecError` when it is not a :class:`Motion`."""
    if not isinstance(motion, Motion):
        raise SpecError(f"not a Motion: {motion!r}")
    return motion


def as_times(t: object) -> np.ndarray:
    """Times as a 1-D float64 array, checked finite and >= 0 (:class:`SpecError` otherwise)."""
    try:
        arr = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError):
        raise SpecError(f"times must be real numbers, got {t!r}") from None
    if arr.ndim > 1:
        raise SpecError(f"times must be a 1-D array, got shape {arr.shape}")
    arr = arr.reshape(-1)
    if arr.size:
        if not np.isfinite(arr).all():
            raise SpecError(f"times must be finite, got {float(arr[~np.isfinite(arr)][0])!r}")
        low = float(arr.min())
        if low < 0.0:
            raise SpecError(f"times must be >= 0, got {low!r}")
    return arr


# ----------------------------------------------------------------------- evaluation


def evaluate(motion: Motion, t: npt.ArrayLike) -> MotionSample:
    """Exact r(t), v(t), a(t) of ``motion`` at times ``t`` (seconds, shape ``(n,)``)."""
    check_motion(motion)
    return sample_motion(motion, as_times(t))


def sample_motion(motion: Motion, t: np.ndarray) -> MotionSample:
    """:func:`evaluate` for inputs already checked (``t`` a 1-D float64 array)."""
    pos, vel, acc = _eval_track(compile_track(motion.base), t)
    for overlay in motion.overlays:
        comp = compile_track(overlay)
        p, v, a = _eval_track(comp, np.clip(t, comp.start, comp.end))
        pos += p - comp.origin
        inside = ((t >= comp.start) & (t <= comp.end))[:, None]
        vel += np.where(inside, v, 0.0)
        acc += np.where(inside, a, 0.0)
    return MotionSample(pos, vel, acc)


def curvature(motion: Motion, t: npt.ArrayLike, signed: bool = False) -> np.ndarray:
    """kappa = |v x a| / |v|^3 (paper eq. 1), ``(n,)``; 0 where the speed is <= :data:`ZERO_SPEED`.

    ``signed=True`` keeps the sign: positive when turning from +X toward +Z.
    """
    found = evaluate(motion, t)
    v, a = found.velocity, found.acceleration
    cross = v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]
    speed = np.hypot(v[:, 0], v[:, 1])
    moving = speed > ZERO_SPEED
    kappa = np.zeros_like(speed)
    kappa[moving] = cross[moving] / speed[moving] ** 3
    return kappa if signed else np.abs(kappa)
