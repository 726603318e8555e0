"""The motion-primitive interface and its registry: what every token type's behaviour
provides, and the lookup from a token to its primitive (:mod:`generators.primitives`)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, NamedTuple, TypeVar, cast

import numpy as np

from schemas.errors import SpecError
from schemas.motion import Token

TokenT = TypeVar("TokenT", bound=Token)
#: How far from the table (units) a planar token may find the object at its start.
ON_TABLE = 1e-9

#: Position, velocity and acceleration, each ``(n, 2)``.
XZ = tuple[np.ndarray, np.ndarray, np.ndarray]
#: ``(x_min, x_max, z_min, z_max)``.
Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class Piece:
    """One token placed on the global clock with absolute parameters ``p`` (their layout
    is the primitive's own, see its module)."""

    primitive: Shape
    t0: float
    duration: float
    p: tuple[float, ...]

    def __post_init__(self) -> None:
        # -0.0 == 0.0, so equal motions share cache entries: canonical zeros keep the
        # output independent of which of them was compiled first.
        object.__setattr__(self, "p", tuple(float(x) + 0.0 for x in self.p))
        object.__setattr__(self, "t0", self.t0 + 0.0)

    def evaluate(self, tau: np.ndarray) -> XZ:
        """Closed-form position, velocity and acceleration ``(n, 2)`` at local times ``tau``."""
        return self.primitive.evaluate(self, tau)


class EndState(NamedTuple):
    """Where a piece leaves off: position ``(2,)``, heading, speed and signed curvature."""

    position: np.ndarray
    heading: float
    speed: float
    curvature: float


@dataclass(frozen=True)
class Segment:
    """A stretch of time on which one analytic description of the velocity holds.

    ``line``: velocity along the fixed direction ``u`` (``still`` if it is zero);
    ``arc``: constant ``speed`` with heading ``heading + rate (t - t0)``;
    ``general``: anything else (clothoids, drifting harmonics, active overlays).
    """

    t0: float
    t1: float
    kind: str
    piece: Piece | None = None
    still: bool = False
    u: tuple[float, float] = (1.0, 0.0)
    heading: float = 0.0
    speed: float = 0.0
    rate: float = 0.0


@dataclass(frozen=True)
class FlightArc:
    """A stretch of vertical motion ``y0 + v0 tau - g tau^2 / 2`` from ``t0``; ``g`` 0 is a rest."""

    t0: float
    y0: float
    v0: float
    g: float


class Shape(ABC):
    """The closed forms of a placed piece (what a :class:`Piece` calls, whatever its token).

    Abstract: a primitive that leaves one out cannot be made, so cannot be registered."""

    @abstractmethod
    def evaluate(self, piece: Piece, tau: np.ndarray) -> XZ:
        """Closed-form position, velocity and acceleration ``(n, 2)`` at local times ``tau``."""
        ...

    @abstractmethod
    def natural_heading(self, piece: Piece, tau: float) -> float:
        """Direction of travel implied by the parameters where the speed is zero."""
        ...

    @abstractmethod
    def segment(self, piece: Piece, t0: float, t1: float) -> Segment:
        """The piece on ``[t0, t1)`` as a line, arc or general segment."""
        ...

    @abstractmethod
    def distance(self, piece: Piece, tau: np.ndarray) -> np.ndarray:
        """Closed-form distance travelled since the piece's start (line and arc segments only)."""
        ...

    @abstractmethod
    def bounds(self, piece: Piece, span: float) -> Box:
        """Exact ``(x_min, x_max, z_min, z_max)`` of the position over local ``[0, span]``."""
        ...


class Primitive(Shape, Generic[TokenT]):
    """The motion behaviour of one token type: placing it (:meth:`place`), its piece's
    closed forms (:class:`Shape`) and its elevation; :meth:`lift` defaults to staying on
    the table (only ``P`` leaves it)."""

    @abstractmethod
    def place(self, token: TokenT, t0: float, prev: EndState | None) -> Piece:
        """``token`` on the global clock from ``t0``, translated to start where ``prev`` ends."""
        ...

    def lift(self, token: TokenT, index: int, t0: float, t1: float, y: float) -> tuple[list[FlightArc], float]:
        """The elevation arcs of ``token`` (base-track token ``index``) on ``[t0, t1)`` when
        the object enters it at height ``y``, and the height at ``t1``. A planar token
        needs the object on the table."""
        if y > ON_TABLE:
            raise SpecError(
                f"token {index} ({token.type}) starts at {t0:.3f} s with the object still {y:.3f} units in the "
                f"air: a planar token after a projectile needs it back on the table"
            )
        return [FlightArc(t0, 0.0, 0.0, 0.0)], 0.0


_REGISTRY: dict[type, Primitive[Token]] = {}


def register(token_type: type[TokenT]) -> Callable[[type[Primitive[TokenT]]], type[Primitive[TokenT]]]:
    """Class decorator: the decorated primitive handles tokens of ``token_type`` (one each)."""

    def decorate(cls: type[Primitive[TokenT]]) -> type[Primitive[TokenT]]:
        if token_type in _REGISTRY:
            raise ValueError(f"a primitive for {token_type.__name__} is already registered")
        _REGISTRY[token_type] = cast("Primitive[Token]", cls())
        return cls

    return decorate


def primitive_for(token: TokenT) -> Primitive[TokenT]:
    """The registered primitive of ``token``'s type."""
    found = _REGISTRY.get(type(token))
    if found is None:
        raise SpecError(f"not a motion token: {token!r}")
    return cast("Primitive[TokenT]", found)


def registered() -> tuple[type, ...]:
    """The token types that have a primitive, in registration order."""
    return tuple(_REGISTRY)
