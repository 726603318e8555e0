"""Object shapes: one class per shape of :mod:`schemas.objects`, found through a registry.

Each shape name a category may give (``sphere``, ``cylinder``, ``box``) has one
:class:`ObjectShape` subclass in a module of this package, registered with
:func:`register`. The shape holds everything that depends on it: its dims and their
count, nominal width and resting height, how it rolls, its signed distance (contact,
grasp), its hull points (visibility), footprint reach (the recipe's grids), its
silhouette and headings (the perception policies), its visual parts (the scene) and the
solid its obstacle clearance is measured on. :mod:`schemas.objects`, :mod:`generators.contact`,
:mod:`generators.grasp`, :mod:`generators.visibility`, :mod:`generators.grids`,
:mod:`generators.scene`, :mod:`generators.clearance`, :mod:`generators.rolling`,
:mod:`generators.projectile` and :mod:`pipeline.policies.silhouette` only call those
methods through :func:`shape_named` (or :attr:`schemas.objects.ObjectCategory.geometry`).

**A new shape touches two files:** one new module here, ``schemas/shapes/<name>.py``,
holding its ``@register("<name>")`` class, and the categories that use it in
``schemas/objects.py`` (``OBJECTS``). Every module of this package is imported below,
so nothing else lists it.
"""

from __future__ import annotations

import importlib
import pkgutil

from schemas.shapes.base import (
    ROLL_MODES,
    SOLIDS,
    ObjectShape,
    Solid,
    VisualPart,
    register,
    registered,
    shape_named,
    unregister,
)

# Registration is by import: load every module of the package once, in name order.
for _module in sorted(m.name for m in pkgutil.iter_modules(__path__)):
    if _module != "base":
        importlib.import_module(f"{__name__}.{_module}")

__all__ = [
    "ROLL_MODES",
    "SOLIDS",
    "ObjectShape",
    "Solid",
    "VisualPart",
    "register",
    "registered",
    "shape_named",
    "unregister",
]
