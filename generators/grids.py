"""Parameter grids of the Dyana-12M recipe, and analytic feasibility of their motions.

A *parameter configuration* is one point of a motion type's product grid: the motion
parameters only (object, hand, format and timing are drawn per episode on top).

==========  ====================================================  =======  ========  ======
type        grid axes (values)                                    product  feasible  table
==========  ====================================================  =======  ========  ======
linear      start x (9: -3..3 step .75) x start z (11: 2..7 step   63,360    35,978  23,520
            .5) x direction (16, 22.5 deg apart) x speed (8: .6..2
            unit/s step .2) x relative acceleration (5: -.2..+.2
            /s step .1; acceleration = relative x speed)
circular    centre x (11: -2.5..2.5 step .5) x centre z (9:        77,616    52,976  44,508
            2.5..6.5 step .5) x radius (7: .5..2 step .25) x
            angular velocity (7: .5..2 rad/s step .25) x start
            angle (8, 45 deg apart) x turn (+1, -1)
harmonic    centre x (7: -2.4..2.4 step .8) x centre z (5: 3..6   123,480    66,952  27,021
            step .75) x axis (6, 30 deg apart over [0, 180)) x
            amplitude (7: .5..2 step .25) x frequency (7: .2, .25,
            .3, .35, .4, .5, .6 Hz) x phase (4, 90 deg apart) x
            drift (3: -.1, 0, +.1 unit/s across the axis)
==========  ====================================================  =======  ========  ======

Each product grid is filtered to the configurations that are *feasible by
construction* (:func:`config_pool`): the object's centre stays in the workspace, the
object stays in the camera's view and moves at most :data:`MAX_SPEED`, for every
object of the recipe and for :data:`POOL_SECONDS` of motion (linear: the longest
direct-act episode; circular: any duration, the whole circle is checked; harmonic: the
longest harmonic episode). The feasible configurations are put in a fixed order by a
seeded permutation (:data:`GRID_SEED`); the first ``TABLE_SIZES[type]`` of them are
the Dyana-12M configuration table (Figure 4(b) of the paper: 23,520 linear, 44,508
circular, 27,021 harmonic) and the rest are held out for ``test-1k``.

Randomness here and in the recipe uses only ``Generator.random`` (53 bits of the bit
generator per double), never ``integers``, ``permutation`` or ``choice``, whose
algorithms NumPy may change between versions. Bounds are closed forms
(exact for a line, the whole orbit for an arc or an oscillation) evaluated with
elementwise NumPy arithmetic, so a batch of one and a batch of many give the same bits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np

from generators.camera import in_view
from generators.visibility import rest_shadow_z
from schemas.errors import SpecError
from schemas.objects import OBJECTS
from schemas.scene import (
    MOTION_TYPES,
    WORKSPACE_X,
    WORKSPACE_Z,
)

#: Figure 4(b): unique parameter configurations of each motion type in Dyana-12M.
TABLE_SIZES = {"linear": 23_520, "circular": 44_508, "harmonic": 27_021}
#: Seed of the fixed permutation that orders each type's feasible configurations.
GRID_SEED = 12_000_000
#: Fastest plausible target for a hand to intercept (units/s; 1 unit = 10 cm).
MAX_SPEED = 3.0
#: Seconds of motion every pooled configuration is feasible for (None: any duration).
POOL_SECONDS = {"linear": 2.0, "circular": None, "harmonic": 6.0}

#: Object sizes: each category's nominal size times one of these factors.
SIZE_FACTORS = (0.85, 0.925, 1.0, 1.075, 1.15)
OBJECT_NAMES = tuple(OBJECTS)


def _axis(start: float, stop: float, num: int) -> np.ndarray:
    return np.round(np.linspace(start, stop, num), 6)


def _angles(count: int, step_deg: float) -> np.ndarray:
    return np.radians(np.arange(count) * step_deg)


#: The grid axes of each motion type, in product order (the last axis varies fastest).
GRID_AXES: dict[str, dict[str, np.ndarray]] = {
    "linear": {
        "start_x": _axis(-3.0, 3.0, 9),
        "start_z": _axis(2.0, 7.0, 11),
        "direction": _angles(16, 22.5),
        "speed": _axis(0.6, 2.0, 8),
        "relative_acceleration": _axis(-0.2, 0.2, 5),
    },
    "circular": {
        "centre_x": _axis(-2.5, 2.5, 11),
        "centre_z": _axis(2.5, 6.5, 9),
        "radius": _axis(0.5, 2.0, 7),
        "angular_velocity": _axis(0.5, 2.0, 7),
        "start_angle": _angles(8, 45.0),
        "turn": np.array([1.0, -1.0]),
    },
    "harmonic": {
        "centre_x": _axis(-2.4, 2.4, 7),
        "centre_z": _axis(3.0, 6.0, 5),
        "axis": _angles(6, 30.0),
        "amplitude": _axis(0.5, 2.0, 7),
        "frequency": np.array([0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6]),
        "phase": _angles(4, 90.0),
        "drift": np.array([-0.1, 0.0, 0.1]),
    },
}


def _object_geometry() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sizes, footprint radii, top heights), each (categories, size factors).

    The footprint radius bounds the object's horizontal extent about its centre
    whatever its heading (a lying cylinder's half diagonal, a box's half diagonal).
    """
    sizes = np.empty((len(OBJECT_NAMES), len(SIZE_FACTORS)))
    radii = np.empty_like(sizes)
    tops = np.empty_like(sizes)
    for i, name in enumerate(OBJECT_NAMES):
        category = OBJECTS[name]
        for j, factor in enumerate(SIZE_FACTORS):
            size = round(category.nominal_size * factor, 4)
            radius = category.geometry.reach(category.scaled_dims(size), category.lying)
            sizes[i, j] = size
            radii[i, j] = radius
            tops[i, j] = 2.0 * category.half_height(size)
    return sizes, radii, tops


OBJECT_SIZES, OBJECT_RADII, OBJECT_TOPS = _object_geometry()


def centre_bounds(motion_type: str, cols: dict[str, np.ndarray], seconds: np.ndarray | None) -> tuple[np.ndarray, ...]:
    """(x_min, x_max, z_min, z_max) of the object's centre over ``[0, seconds]``.

    Linear: exact, from the extremes of s(t) = v t + a t^2 / 2 (a turning point counts
    when it falls inside). Circular: the whole circle. Harmonic: the whole swing plus the
    drift's displacement; ``seconds=None`` is allowed only for circular (the others raise).
    """
    if motion_type == "linear":
        if seconds is None:
            raise SpecError("linear bounds need a duration")
        v, a = cols["speed"], cols["acceleration"]
        s_end = v * seconds + 0.5 * a * seconds * seconds
        with np.errstate(divide="ignore", invalid="ignore"):
            t_turn = np.where(a < 0.0, -v / a, np.inf)
        t_turn = np.where(t_turn < seconds, t_turn, 0.0)
        s_turn = v * t_turn + 0.5 * a * t_turn * t_turn
        s_lo = np.minimum(np.minimum(0.0, s_end), s_turn)
        s_hi = np.maximum(np.maximum(0.0, s_end), s_turn)
        dx_lo, dx_hi = cols["ux"] * s_lo, cols["ux"] * s_hi
        dz_lo, dz_hi = cols["uz"] * s_lo, cols["uz"] * s_hi
        return (
            cols["start_x"] + np.minimum(dx_lo, dx_hi),
            cols["start_x"] + np.maximum(dx_lo, dx_hi),
            cols["start_z"] + np.minimum(dz_lo, dz_hi),
            cols["start_z"] + np.maximum(dz_lo, dz_hi),
        )
    if motion_type == "circular":
        r = cols["radius"]
        return cols["centre_x"] - r, cols["centre_x"] + r, cols["centre_z"] - r, cols["centre_z"] + r
    if motion_type == "harmonic":
        if seconds is None:
            raise SpecError("harmonic bounds need a duration")
        sx, sz = cols["swing_x"], cols["swing_z"]
        px, pz = cols["drift_x"] * seconds, cols["drift_z"] * seconds
        return (
            cols["centre_x"] - sx + np.minimum(px, 0.0),
            cols["centre_x"] + sx + np.maximum(px, 0.0),
            cols["centre_z"] - sz + np.minimum(pz, 0.0),
            cols["centre_z"] + sz + np.maximum(pz, 0.0),
        )
    raise SpecError(f"unknown motion type {motion_type!r} (expected one of {list(MOTION_TYPES)})")


def max_speed(motion_type: str, cols: dict[str, np.ndarray], seconds: np.ndarray | None) -> np.ndarray:
    """Largest speed of the object's centre over ``[0, seconds]`` (units/s)."""
    if motion_type == "linear":
        if seconds is None:
            raise SpecError("linear bounds need a duration")
        v, a = cols["speed"], cols["acceleration"]
        return np.maximum(np.abs(v), np.abs(v + a * seconds))
    if motion_type == "circular":
        return cols["radius"] * cols["angular_velocity"]
    if motion_type == "harmonic":
        return 2.0 * math.pi * cols["frequency"] * cols["amplitude"] + np.abs(cols["drift"])
    raise SpecError(f"unknown motion type {motion_type!r} (expected one of {list(MOTION_TYPES)})")





def feasible(
    motion_type: str,
    cols: dict[str, np.ndarray],
    seconds: np.ndarray | None,
    radius: np.ndarray,
    top: np.ndarray,
) -> np.ndarray:
    """Feasibility of each row: the centre stays in the workspace, the object's bounding
    box (centre bounds grown by its footprint ``radius``, from the table up to ``top``)
    stays in the view frustum and wholly beyond the resting hand's silhouette (so the
    hand never hides it: :func:`generators.visibility.rest_shadow_z`), and the speed
    stays at most :data:`MAX_SPEED`.

    The frustum is convex, so checking the box's eight corners covers the whole path.
    """
    x0, x1, z0, z1 = centre_bounds(motion_type, cols, seconds)
    ok = (x0 >= WORKSPACE_X[0]) & (x1 <= WORKSPACE_X[1]) & (z0 >= WORKSPACE_Z[0]) & (z1 <= WORKSPACE_Z[1])
    ok &= z0 - radius > rest_shadow_z()
    ok &= max_speed(motion_type, cols, seconds) <= MAX_SPEED
    zero = np.zeros_like(x0)
    for x in (x0 - radius, x1 + radius):
        for z in (z0 - radius, z1 + radius):
            for y in (zero, zero + top):
                ok &= in_view(x, y, z)
    return ok


def _derive(motion_type: str, cols: dict[str, np.ndarray]) -> None:
    """Add the derived columns the tokens and bounds use (rounded, no negative zeros)."""
    if motion_type == "linear":
        cols["acceleration"] = np.round(cols["relative_acceleration"] * cols["speed"], 6) + 0.0
        cols["ux"] = np.cos(cols["direction"])
        cols["uz"] = np.sin(cols["direction"])
    elif motion_type == "circular":
        cols["period_s"] = 2.0 * math.pi / cols["angular_velocity"]
    else:
        cols["swing_x"] = cols["amplitude"] * np.abs(np.cos(cols["axis"]))
        cols["swing_z"] = cols["amplitude"] * np.abs(np.sin(cols["axis"]))
        cols["drift_x"] = np.round(-np.sin(cols["axis"]) * cols["drift"], 6) + 0.0
        cols["drift_z"] = np.round(np.cos(cols["axis"]) * cols["drift"], 6) + 0.0
        cols["period_s"] = 1.0 / cols["frequency"]


def derived_columns(motion_type: str, axes: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The grid axes ``axes`` (one value per row) with the derived columns :func:`feasible` reads."""
    cols = dict(axes)
    _derive(motion_type, cols)
    return cols


@dataclass(frozen=True, eq=False)
class ConfigPool:
    """A motion type's feasible configurations in their fixed order.

    Rows ``[0, table_size)`` are the Dyana-12M table, the rest are held out.
    ``grid_ids`` are the rows' flat indices in the product grid: a configuration's
    identity. ``cols`` holds the grid axes and derived columns, one value per row.
    """

    motion_type: str
    grid_size: int
    grid_ids: np.ndarray
    cols: dict[str, np.ndarray]
    table_size: int

    @property
    def size(self) -> int:
        return len(self.grid_ids)

    @property
    def heldout_size(self) -> int:
        return self.size - self.table_size

    def rows(self, index: np.ndarray) -> dict[str, np.ndarray]:
        """The columns of the given rows."""
        return {name: values[index] for name, values in self.cols.items()}


def worst_object() -> tuple[float, float]:
    """The largest footprint radius and top height over every recipe object."""
    return float(OBJECT_RADII.max()), float(OBJECT_TOPS.max())


@cache
def config_pool(motion_type: str) -> ConfigPool:
    """Enumerate, filter and order a motion type's product grid (cached per process)."""
    if motion_type not in GRID_AXES:
        raise SpecError(f"unknown motion type {motion_type!r} (expected one of {list(MOTION_TYPES)})")
    axes = GRID_AXES[motion_type]
    mesh = np.meshgrid(*axes.values(), indexing="ij")
    cols = {name: grid.ravel() for name, grid in zip(axes, mesh)}
    _derive(motion_type, cols)
    grid_size = mesh[0].size
    seconds = POOL_SECONDS[motion_type]
    span = None if seconds is None else np.full(grid_size, float(seconds))
    radius, top = worst_object()
    ok = feasible(motion_type, cols, span, np.full(grid_size, radius), np.full(grid_size, top))
    ids = np.flatnonzero(ok)
    table_size = TABLE_SIZES[motion_type]
    if len(ids) < table_size:
        raise SpecError(f"{motion_type} grid has {len(ids)} feasible configurations, fewer than {table_size}")
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([GRID_SEED, MOTION_TYPES.index(motion_type)])))
    order = np.argsort(rng.random(len(ids)), kind="stable")
    ids = ids[order]
    ids.setflags(write=False)
    picked = {name: np.ascontiguousarray(values[ids]) for name, values in cols.items()}
    for values in picked.values():
        values.setflags(write=False)
    return ConfigPool(motion_type, grid_size, ids, picked, table_size)
