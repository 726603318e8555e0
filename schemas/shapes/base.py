"""The object-shape interface and its registry: what every shape of :mod:`schemas.objects`
provides, and the lookup from a shape's name to it (:mod:`schemas.shapes`).

Dims are a category's geometry scaled to its size (:meth:`schemas.objects.ObjectCategory.scaled_dims`);
``lying`` is the category's flag (a shape that has no lying pose ignores it). Engines see a
shape through pybullet's three primitive solids (:data:`SOLIDS`): its visual parts and its
clearance solid are made of them, so :mod:`generators.scene` and :mod:`generators.clearance`
need nothing per shape.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, TypeVar

import numpy as np

from schemas.errors import SpecError
from schemas.names import shorten

#: pybullet's primitive solids, the parts every shape is drawn and measured with.
SOLIDS = ("sphere", "cylinder", "box")
#: How an object rolls without slipping: ``ball`` (any direction, omega = (+Y x v) / r) or
#: ``axle`` (about a horizontal axis kept normal to its path).
ROLL_MODES = ("ball", "axle")
IDENTITY = (0.0, 0.0, 0.0, 1.0)
#: Rotate a pybullet cylinder's local Z axis onto X, and onto Y.
Z_TO_X = (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5))
Z_TO_Y = (-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))
#: The 8 corners of the unit box (signs of x, y, z), x slowest.
BOX_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
#: Points sampling round surfaces for hulls: directions on the sphere, points on a circle.
SPHERE_POINTS = 96
RIM_POINTS = 48


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) directions on the unit sphere (Fibonacci lattice)."""
    k = np.arange(n, dtype=np.float64) + 0.5
    polar = np.arccos(1.0 - 2.0 * k / n)
    azimuth = np.pi * (1.0 + 5.0**0.5) * k
    return np.stack([np.cos(azimuth) * np.sin(polar), np.cos(polar), np.sin(azimuth) * np.sin(polar)], axis=-1)


UNIT_SPHERE = fibonacci_sphere(SPHERE_POINTS)
_ANGLES = np.linspace(0.0, 2.0 * np.pi, RIM_POINTS, endpoint=False)
UNIT_CIRCLE = np.stack([np.cos(_ANGLES), np.sin(_ANGLES)], axis=-1)


def rim(centre: np.ndarray, axis: np.ndarray, radius: float) -> np.ndarray:
    """(RIM_POINTS, 3) points on the circle of ``radius`` about ``centre`` perpendicular to unit ``axis``."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    return centre + radius * (UNIT_CIRCLE[:, :1] * u + UNIT_CIRCLE[:, 1:] * v)


@dataclass(frozen=True)
class VisualPart:
    """One visual primitive of a body in its frame: ``kind`` one of :data:`SOLIDS`, ``dims``
    (radius,), (radius, length) along local Z, or half extents."""

    kind: str
    dims: tuple[float, ...]
    rgba: tuple[float, float, float, float]
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = IDENTITY

    def __post_init__(self) -> None:
        if self.kind not in SOLIDS:
            raise SpecError(f"visual part: unknown solid {shorten(repr(self.kind))} (expected one of {list(SOLIDS)})")


@dataclass(frozen=True)
class Solid:
    """The convex solid a shape's clearance to obstacles is measured on: ``kind`` one of
    :data:`SOLIDS`; ``dims`` (radius,), (radius, half length) or half extents; ``axes``
    the object-frame axes that become the solid's X, Y, Z (a cylinder runs along its Z)."""

    kind: str
    dims: tuple[float, ...]
    axes: tuple[int, int, int] = (0, 1, 2)

    def __post_init__(self) -> None:
        if self.kind not in SOLIDS:
            raise SpecError(f"clearance solid: unknown kind {shorten(repr(self.kind))} (expected one of {list(SOLIDS)})")


class ObjectShape(ABC):
    """Everything that depends on an object's shape; one registered instance per shape.

    Abstract: a shape that leaves a method out cannot be made, so cannot be registered."""

    #: The shape's name in :class:`schemas.objects.ObjectCategory` (set by :func:`register`).
    name: ClassVar[str] = ""
    #: What the category's nominal ``dims`` are, in order (their count is checked).
    dims: ClassVar[tuple[str, ...]] = ()

    def nominal_size(self, dims: tuple[float, ...]) -> float:
        """The characteristic width of ``dims`` (what an episode's ``object_size`` sets)."""
        return 2.0 * dims[0]

    @abstractmethod
    def half_height(self, dims: tuple[float, ...], lying: bool) -> float:
        """Height of the centre above the table when the object rests on it."""

    @abstractmethod
    def roll_mode(self, lying: bool) -> str | None:
        """How the object rolls (one of :data:`ROLL_MODES`), None if it cannot."""

    def axis(self, lying: bool) -> int:
        """The local axis a round shape's axis runs along (0 = X lying, 1 = Y upright)."""
        return 0 if lying else 1

    @abstractmethod
    def signed_distance(self, points: np.ndarray, dims: tuple[float, ...], axis: int) -> np.ndarray:
        """Signed distance (...,) of local points (..., 3) to the surface (negative inside);
        ``axis`` is the local axis of a round shape (2 = Z, pybullet's own primitive)."""

    @abstractmethod
    def hull_points(self, dims: tuple[float, ...], lying: bool) -> np.ndarray:
        """(k, 3) points in the object's frame whose convex hull is the object (visibility)."""

    @abstractmethod
    def reach(self, dims: tuple[float, ...], lying: bool, hypot: Callable[[float, float], float] = math.hypot) -> float:
        """The horizontal extent about the centre whatever the heading (its footprint's
        radius). ``hypot`` combines two legs: each caller keeps the one it was written
        with (``math.hypot`` and ``numpy.hypot`` differ in the last bit)."""

    @abstractmethod
    def silhouette_points(self, dims: tuple[float, ...], lying: bool, heading: float) -> np.ndarray:
        """(m, 3) points whose hull is the body, centre at the origin, as a policy's
        template search draws it; ``heading`` turns a lying shape's axis in the XZ plane."""

    def headings(self, lying: bool) -> tuple[float, ...]:
        """The headings a template search tries (one unless the shape looks different turned)."""
        return (0.0,)

    @abstractmethod
    def visual_parts(self, dims: tuple[float, ...], lying: bool, rgba, mark) -> list[VisualPart]:
        """The body's visual parts in the object's frame: the first its colour ``rgba``, the
        rest markings in ``mark`` (a rolling body's markings show it turn)."""

    @abstractmethod
    def solid(self, dims: tuple[float, ...], lying: bool) -> Solid:
        """The convex solid the object's clearance to obstacles is measured on."""


ShapeT = TypeVar("ShapeT", bound=type[ObjectShape])
_REGISTRY: dict[str, ObjectShape] = {}


def register(name: str) -> Callable[[ShapeT], ShapeT]:
    """Class decorator: the decorated class is the shape ``name`` (one class per name)."""

    def decorate(cls: ShapeT) -> ShapeT:
        if not isinstance(name, str) or not name:
            raise ValueError(f"a shape needs a non-empty name, got {name!r}")
        if name in _REGISTRY:
            raise ValueError(f"a shape named {name!r} is already registered")
        cls.name = name
        _REGISTRY[name] = cls()
        return cls

    return decorate


def unregister(name: str) -> None:
    """Remove the shape ``name`` (for tests that register a toy shape)."""
    _REGISTRY.pop(name, None)


def shape_named(name: str) -> ObjectShape:
    """The registered shape ``name``; SpecError naming it and the known ones."""
    found = _REGISTRY.get(name) if isinstance(name, str) else None
    if found is None:
        raise SpecError(f"unknown shape {shorten(repr(name))} (expected one of {sorted(_REGISTRY)})")
    return found


def registered() -> tuple[str, ...]:
    """The names of the registered shapes, in registration order."""
    return tuple(_REGISTRY)
