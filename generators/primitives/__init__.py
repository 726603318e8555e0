"""Motion primitives: one class per motion token type, found through a registry.

Each token letter of :mod:`schemas.motion` (``L`` line, ``A`` arc, ``H`` harmonic,
``C`` clothoid, ``P`` projectile) has one :class:`Primitive` subclass in a module of this
package, registered for its token class with :func:`register`. The primitive holds all of
the token's motion behaviour: placing it on the clock after the previous token
(``place``), closed-form position/velocity/acceleration (``evaluate``), its heading at
rest, its line/arc/general segments and arc length, exact XZ bounds, and its elevation
(``lift``; planar tokens keep the object on the table). :mod:`generators.tracks`,
:mod:`generators.segments`, :mod:`generators.bounds`, :mod:`generators.ballistics` and
:mod:`generators.rolling` only call those methods through :func:`primitive_for`.

**A new primitive touches two files:** its token dataclass (fields, validation, its
letter in ``TOKEN_TYPES``) in ``schemas/motion.py``, and one new module here,
``generators/primitives/<name>.py``, holding its ``@register(<Token>)`` class. Every
module of this package is imported below, so nothing else lists it.
"""

from __future__ import annotations

import importlib
import pkgutil

from generators.primitives.base import (
    EndState,
    FlightArc,
    Piece,
    Primitive,
    Segment,
    primitive_for,
    register,
    registered,
)

# Registration is by import: load every module of the package once, in name order.
for _module in sorted(m.name for m in pkgutil.iter_modules(__path__)):
    importlib.import_module(f"{__name__}.{_module}")

__all__ = ["EndState", "FlightArc", "Piece", "Primitive", "Segment", "primitive_for", "register", "registered"]
