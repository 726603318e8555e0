"""Validators for spec fields: each returns the value as Dyana stores it or raises a
:class:`SpecError` naming the field (``owner.name``) and the bad value, cut short."""

from __future__ import annotations

import json
import math
import numbers
from typing import Any

from schemas.errors import SpecError
from schemas.names import shorten

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


def finite(owner: str, name: str, value: Any) -> float:
    """A real, finite number (not a bool) as a float."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise SpecError(f"{owner}.{name} must be a number, got {shorten(repr(value))}")
    try:
        value = float(value)
    except OverflowError:
        raise SpecError(f"{owner}.{name} must be finite, got {shorten(repr(value))}") from None
    if not math.isfinite(value):
        raise SpecError(f"{owner}.{name} must be finite, got {shorten(repr(value))}")
    return value


def pair(owner: str, name: str, value: Any) -> Vec2:
    """A finite ``[x, z]`` pair as a tuple."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise SpecError(f"{owner}.{name} must be a pair [x, z], got {shorten(repr(value))}")
    return (finite(owner, f"{name}[0]", value[0]), finite(owner, f"{name}[1]", value[1]))


def triple(owner: str, name: str, value: Any) -> Vec3:
    """A finite ``[x, y, z]`` triple as a tuple."""
    if not isinstance(value, (tuple, list)) or len(value) != 3:
        raise SpecError(f"{owner}.{name} must be a triple [x, y, z], got {shorten(repr(value))}")
    return (finite(owner, f"{name}[0]", value[0]), finite(owner, f"{name}[1]", value[1]),
            finite(owner, f"{name}[2]", value[2]))


def positive(owner: str, name: str, value: Any) -> float:
    """A finite number > 0."""
    value = finite(owner, name, value)
    if value <= 0:
        raise SpecError(f"{owner}.{name} must be > 0, got {shorten(repr(value))}")
    return value


def non_negative(owner: str, name: str, value: Any) -> float:
    """A finite number >= 0."""
    value = finite(owner, name, value)
    if value < 0:
        raise SpecError(f"{owner}.{name} must be >= 0, got {shorten(repr(value))}")
    return value


def load_json(what: str, text: Any) -> Any:
    """``json.loads`` whose every failure (bad syntax, wrong type, nesting too deep for
    the parser) is a :class:`SpecError` naming ``what``."""
    if not isinstance(text, (str, bytes, bytearray)):
        raise SpecError(f"{what} JSON must be text, got {type(text).__name__}")
    try:
        return json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SpecError(f"{what} is not valid JSON: {exc}") from exc
    except ValueError as exc:  # e.g. an integer over Python's 4,300-digit conversion limit
        raise SpecError(f"{what} holds a number Dyana cannot read: {shorten(str(exc), 160)}") from None
    except RecursionError:
        raise SpecError(f"{what} JSON is nested too deeply") from None
