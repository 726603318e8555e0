"""Static obstacles on the table (paper A.11, obstacle-aware grasping).

An obstacle is a box resting on the table (its bottom at Y = 0), turned by ``yaw``
about +Y, of a named category that fixes its colour and nominal proportions. A spec
lists at most :data:`MAX_OBSTACLES`; its JSON carries them under ``obstacles`` only
when there are any, so specs without obstacles keep their canonical JSON and hash.

The ground-truth hand keeps :data:`OBSTACLE_MARGIN` from every obstacle at every frame;
a hand whose surface comes within :data:`CONTACT_CLEARANCE` of one touches it (an
obstacle collision event, reported by ``scoring eval``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from schemas.errors import SpecError
from schemas.limits import MAX_ANGLE
from schemas.names import shorten
from schemas.scene import TABLE_X, TABLE_Z
from schemas.values import finite, relocate

#: Most obstacles one spec may hold.
MAX_OBSTACLES = 8
#: Clearance (units) the ground-truth hand keeps from every obstacle at every frame (1.5 cm).
OBSTACLE_MARGIN = 0.15
#: A hand-obstacle clearance at or below this (units) is a contact (a collision event).
CONTACT_CLEARANCE = 0.0
#: Half extents (units) an obstacle may have: from a 1 cm slab to a 1.2 m crate.
HALF_EXTENT_RANGE = (0.05, 6.0)


@dataclass(frozen=True)
class ObstacleCategory:
    """A named kind of obstacle: colour and nominal half extents ``(hx, hy, hz)``."""

    name: str
    half_extents: tuple[float, float, float]
    rgba: tuple[float, float, float, float]


#: Obstacle categories. Colours are unlike every target object's and the table's.
OBSTACLE_CATEGORIES: dict[str, ObstacleCategory] = {
    c.name: c
    for c in (
        ObstacleCategory("crate", (0.6, 0.5, 0.6), (0.62, 0.45, 0.25, 1.0)),
        ObstacleCategory("book", (0.75, 0.15, 0.55), (0.30, 0.22, 0.52, 1.0)),
        ObstacleCategory("brick", (0.55, 0.28, 0.28), (0.70, 0.30, 0.22, 1.0)),
    )
}


def _number(name: str, value: Any, limit: float | None = None) -> float:
    owner, _, field = name.partition(".")
    return finite(owner, field, value, limit)


def _pair(name: str, value: Any, width: int) -> tuple[float, ...]:
    if not isinstance(value, (tuple, list)) or len(value) != width:
        raise SpecError(f"{name} must be a list of {width} numbers, got {shorten(repr(value))}")
    return tuple(_number(f"{name}[{k}]", v) for k, v in enumerate(value))


@dataclass(frozen=True)
class Obstacle:
    """A box on the table: ``centre`` (x, z) of its footprint, ``half_extents``
    (hx, hy, hz) in its own frame (``hy`` is half its height), ``yaw`` about +Y (rad)."""

    category: str
    centre: tuple[float, float]
    half_extents: tuple[float, float, float]
    yaw: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.category, str) or self.category not in OBSTACLE_CATEGORIES:
            raise SpecError(
                f"obstacle.category must be one of {sorted(OBSTACLE_CATEGORIES)}, got {shorten(repr(self.category))}"
            )
        centre = _pair("obstacle.centre", self.centre, 2)
        if not (TABLE_X[0] <= centre[0] <= TABLE_X[1] and TABLE_Z[0] <= centre[1] <= TABLE_Z[1]):
            raise SpecError(f"obstacle.centre must lie on the table (x in {TABLE_X}, z in {TABLE_Z}), got {centre}")
        half = _pair("obstacle.half_extents", self.half_extents, 3)
        low, high = HALF_EXTENT_RANGE
        if not all(low <= h <= high for h in half):
            raise SpecError(f"obstacle.half_extents must each be in [{low}, {high}] units, got {shorten(repr(half))}")
        object.__setattr__(self, "centre", centre)
        object.__setattr__(self, "half_extents", half)
        object.__setattr__(self, "yaw", _number("obstacle.yaw", self.yaw, MAX_ANGLE))

    @property
    def rgba(self) -> tuple[float, float, float, float]:
        return OBSTACLE_CATEGORIES[self.category].rgba

    @property
    def height(self) -> float:
        return 2.0 * self.half_extents[1]

    @property
    def position(self) -> tuple[float, float, float]:
        """The box's centre (x, y, z): its footprint's centre, half its height up."""
        return (self.centre[0], self.half_extents[1], self.centre[1])

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        """Its orientation (qx, qy, qz, qw): ``Ry(yaw)``, the turn about +Y."""
        return (0.0, math.sin(0.5 * self.yaw), 0.0, math.cos(0.5 * self.yaw))

    def to_dict(self) -> dict[str, Any]:
        return {
            "category": self.category,
            "centre": list(self.centre),
            "half_extents": list(self.half_extents),
            "yaw": self.yaw,
        }

    @classmethod
    def from_dict(cls, data: Any) -> Obstacle:
        if not isinstance(data, dict):
            raise SpecError(f"an obstacle must be an object, got {shorten(repr(data))}")
        allowed = {"category", "centre", "half_extents", "yaw"}
        unknown = sorted(str(k) for k in set(data) - allowed)
        if unknown:
            raise SpecError(f"obstacle has unknown field(s) {unknown}")
        missing = [k for k in ("category", "centre", "half_extents") if k not in data]
        if missing:
            raise SpecError(f"obstacle is missing field(s) {missing}")
        return cls(**data)


def obstacles_from_list(data: Any) -> tuple[Obstacle, ...]:
    """Validate a spec's ``obstacles`` list; errors name the bad entry."""
    if not isinstance(data, (list, tuple)):
        raise SpecError(f"spec.obstacles must be a list of obstacles, got {shorten(repr(data))}")
    if len(data) > MAX_OBSTACLES:
        raise SpecError(f"spec.obstacles holds at most {MAX_OBSTACLES} obstacles, got {len(data):,}")
    out = []
    for k, item in enumerate(data):
        if isinstance(item, Obstacle):
            out.append(item)
            continue
        try:
            out.append(Obstacle.from_dict(item))
        except SpecError as exc:
            raise relocate(exc, f"spec.obstacles[{k}]") from None
    return tuple(out)


def obstacles_to_list(obstacles: tuple[Obstacle, ...]) -> list[dict[str, Any]]:
    return [o.to_dict() for o in obstacles]
