"""The 11 target object categories (paper 3.4): spheres, cylinders and boxes, 6 rolling.
Everything that depends on a category's shape is its shape's (:mod:`schemas.shapes`).

Sizes are in scene units (1 unit = 10 cm). An episode's ``object_size`` is the
object's characteristic width (sphere and cylinder diameter, box's longer horizontal
edge); the category's nominal shape is scaled uniformly to it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from schemas.errors import SpecError
from schemas.names import shorten
from schemas.shapes import ObjectShape, registered, shape_named

#: An object's allowed width as multiples of its nominal width (see ObjectCategory.size_range).
SIZE_RANGE = (0.5, 2.0)


@dataclass(frozen=True)
class ObjectCategory:
    """A category's nominal geometry. ``dims`` are its shape's (:attr:`ObjectShape.dims`):
    sphere ``(radius,)``; cylinder ``(radius, length)``; box half extents ``(hx, hy, hz)``.
    A ``lying`` cylinder's axis is horizontal; rolling objects roll without slipping.
    """

    name: str
    shape: str
    dims: tuple[float, ...]
    rolling: bool
    rgba: tuple[float, float, float, float]
    lying: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.shape, str) or self.shape not in registered():
            raise SpecError(
                f"object {shorten(repr(self.name))}: unknown shape {shorten(repr(self.shape))} "
                f"(expected one of {sorted(registered())})"
            )
        if len(self.dims) != len(self.geometry.dims) or not all(math.isfinite(d) and d > 0 for d in self.dims):
            raise SpecError(f"object {shorten(repr(self.name))}: bad dims {shorten(repr(self.dims))}")

    @property
    def geometry(self) -> ObjectShape:
        """The registered shape (:mod:`schemas.shapes`) this category is."""
        return shape_named(self.shape)

    @property
    def nominal_size(self) -> float:
        return self.geometry.nominal_size(self.dims)

    @property
    def size_range(self) -> tuple[float, float]:
        """Widths a spec may give this object: half to twice its nominal width (the recipe
        varies it by 0.85-1.15x); beyond, it is another object (a 50 cm tennis ball)."""
        return SIZE_RANGE[0] * self.nominal_size, SIZE_RANGE[1] * self.nominal_size

    def scaled_dims(self, size: float) -> tuple[float, ...]:
        """Geometry scaled so that the characteristic width equals ``size``."""
        k = size / self.nominal_size
        return tuple(d * k for d in self.dims)

    def half_height(self, size: float) -> float:
        """Height of the object's centre above the table (its resting half height)."""
        return self.geometry.half_height(self.scaled_dims(size), self.lying)

    def rolling_radius(self, size: float) -> float:
        """Radius the object rolls on; only meaningful when ``rolling``."""
        return self.scaled_dims(size)[0]


OBJECTS: dict[str, ObjectCategory] = {
    o.name: o
    for o in (
        ObjectCategory("tennis_ball", "sphere", (0.335,), True, (0.80, 0.90, 0.20, 1.0)),
        ObjectCategory("baseball", "sphere", (0.37,), True, (0.95, 0.93, 0.88, 1.0)),
        ObjectCategory("orange", "sphere", (0.40,), True, (1.00, 0.55, 0.05, 1.0)),
        ObjectCategory("soda_can", "cylinder", (0.33, 1.22), True, (0.80, 0.05, 0.10, 1.0), lying=True),
        ObjectCategory("water_bottle", "cylinder", (0.35, 1.80), True, (0.35, 0.65, 0.95, 1.0), lying=True),
        ObjectCategory("paper_roll", "cylinder", (0.55, 1.10), True, (0.97, 0.97, 0.97, 1.0), lying=True),
        ObjectCategory("mug", "cylinder", (0.42, 0.95), False, (0.20, 0.40, 0.75, 1.0)),
        ObjectCategory("cup", "cylinder", (0.38, 0.80), False, (0.15, 0.70, 0.35, 1.0)),
        ObjectCategory("cracker_box", "box", (0.80, 0.30, 0.30), False, (0.85, 0.20, 0.15, 1.0)),
        ObjectCategory("sugar_box", "box", (0.45, 0.25, 0.22), False, (0.95, 0.85, 0.30, 1.0)),
        ObjectCategory("toy_cube", "box", (0.30, 0.30, 0.30), False, (0.55, 0.25, 0.70, 1.0)),
    )
}


def object_category(name: str) -> ObjectCategory:
    """Look a category up by name; a clear error lists the known ones."""
    try:
        return OBJECTS[name]
    except (KeyError, TypeError):
        raise SpecError(f"unknown object {shorten(repr(name))} (expected one of {sorted(OBJECTS)})") from None
