"""Validators for spec fields: each returns the value as Dyana stores it or raises a
:class:`FieldError` naming the field (``owner.name``) and the bad value, cut short.

:func:`load_json` reads spec JSON: a key repeated in an object, at any depth, or an
integer longer than :data:`schemas.limits.MAX_NUMBER_DIGITS` is refused naming its field.
"""

from __future__ import annotations

import json
import math
import numbers
from typing import Any

from schemas.errors import SpecError
from schemas.limits import MAX_NUMBER_DIGITS
from schemas.names import shorten

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


class FieldError(SpecError):
    """A :class:`SpecError` about the field at ``path`` (``C.curvature``, ``spec.seed``):
    ``str`` is ``"{path} {problem}"``. :meth:`at` moves it to where its owner sits."""

    def __init__(self, path: str, problem: str) -> None:
        super().__init__(f"{path} {problem}")
        self.path, self.problem = path, problem

    def __reduce__(self) -> tuple[type[FieldError], tuple[str, str]]:
        return (FieldError, (self.path, self.problem))

    def at(self, where: str) -> FieldError:
        """The same error with the path's owner (up to its first ``.`` or ``[``) replaced by
        ``where``: ``C.curvature`` at ``spec.motion.base[2]`` is ``spec.motion.base[2].curvature``."""
        cuts = [i for i in (self.path.find("."), self.path.find("[")) if i >= 0]
        return FieldError(where + self.path[min(cuts, default=len(self.path)):], self.problem)


def relocate(exc: SpecError, where: str) -> SpecError:
    """``exc`` raised by the part of a spec at ``where``, as the error of the whole."""
    return exc.at(where) if isinstance(exc, FieldError) else SpecError(f"{where}: {exc}")


class LongNumber:
    """An integer of the JSON longer than :data:`MAX_NUMBER_DIGITS` digits, kept as its text
    so the field it sits in is refused by name (never converted: Python refuses beyond 4,300
    digits, and a huge int only costs time)."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return f"{self.text[:20]}... (an integer of {len(self.text.lstrip('-')):,} digits)"


def finite(owner: str, name: str, value: Any, limit: float | None = None) -> float:
    """A real, finite number (not a bool) as a float, of magnitude at most ``limit``."""
    if isinstance(value, LongNumber):
        raise FieldError(f"{owner}.{name}", f"holds at most {MAX_NUMBER_DIGITS} digits, got {value!r}")
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise FieldError(f"{owner}.{name}", f"must be a number, got {shorten(repr(value))}")
    try:
        value = float(value)
    except OverflowError:
        raise FieldError(f"{owner}.{name}", f"must be finite, got {shorten(repr(value))}") from None
    if not math.isfinite(value):
        raise FieldError(f"{owner}.{name}", f"must be finite, got {shorten(repr(value))}")
    if limit is not None and abs(value) > limit:
        raise FieldError(f"{owner}.{name}", f"must be in [{-limit:g}, {limit:g}], got {shorten(repr(value))}")
    return value


def pair(owner: str, name: str, value: Any, limit: float | None = None) -> Vec2:
    """A finite ``[x, z]`` pair as a tuple, each of magnitude at most ``limit``."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise FieldError(f"{owner}.{name}", f"must be a pair [x, z], got {shorten(repr(value))}")
    return (finite(owner, f"{name}[0]", value[0], limit), finite(owner, f"{name}[1]", value[1], limit))


def triple(owner: str, name: str, value: Any, limit: float | None = None) -> Vec3:
    """A finite ``[x, y, z]`` triple as a tuple, each of magnitude at most ``limit``."""
    if not isinstance(value, (tuple, list)) or len(value) != 3:
        raise FieldError(f"{owner}.{name}", f"must be a triple [x, y, z], got {shorten(repr(value))}")
    return (finite(owner, f"{name}[0]", value[0], limit), finite(owner, f"{name}[1]", value[1], limit),
            finite(owner, f"{name}[2]", value[2], limit))


def positive(owner: str, name: str, value: Any, limit: float | None = None) -> float:
    """A finite number > 0 and at most ``limit``."""
    value = finite(owner, name, value)
    if value <= 0 or (limit is not None and value > limit):
        bound = "> 0" if limit is None else f"in (0, {limit:g}]"
        raise FieldError(f"{owner}.{name}", f"must be {bound}, got {shorten(repr(value))}")
    return value


def non_negative(owner: str, name: str, value: Any, limit: float | None = None) -> float:
    """A finite number >= 0 and at most ``limit``."""
    value = finite(owner, name, value)
    if value < 0 or (limit is not None and value > limit):
        bound = ">= 0" if limit is None else f"in [0, {limit:g}]"
        raise FieldError(f"{owner}.{name}", f"must be {bound}, got {shorten(repr(value))}")
    return value


class _Repeated(dict[str, Any]):
    """A JSON object in which ``key`` appeared more than once."""

    key: str


def _object(pairs: list[tuple[str, Any]], repeats: list[_Repeated]) -> dict[str, Any]:
    """``object_pairs_hook``: the object, marked as :class:`_Repeated` (and listed in
    ``repeats``) if a key repeats, so only such input is walked for the key's path."""
    out = dict(pairs)
    if len(out) == len(pairs):
        return out
    repeated = _Repeated(out)
    seen: set[str] = set()
    for key, _ in pairs:
        if key in seen:
            repeated.key = key
            break
        seen.add(key)
    repeats.append(repeated)
    return repeated


def _integer(text: str) -> int | LongNumber:
    return LongNumber(text) if len(text.lstrip("-")) > MAX_NUMBER_DIGITS else int(text)


def _repeated_key(what: str, data: Any) -> str | None:
    """The path of the first repeated key in parsed ``data`` (``what`` is its root), or None."""
    stack: list[tuple[str, Any]] = [(what, data)]
    while stack:
        path, node = stack.pop()
        if isinstance(node, _Repeated):
            return f"{path}.{node.key}"
        if isinstance(node, dict):
            stack.extend((f"{path}.{k}", v) for k, v in reversed(node.items()))
        elif isinstance(node, list):
            stack.extend((f"{path}[{i}]", v) for i, v in reversed(list(enumerate(node))))
    return None


def load_json(what: str, text: Any) -> Any:
    """``json.loads`` whose every failure (bad syntax, wrong type, nesting too deep for
    the parser, a key twice in one object) is a :class:`SpecError` naming ``what``."""
    if not isinstance(text, (str, bytes, bytearray)):
        raise SpecError(f"{what} JSON must be text, got {type(text).__name__}")
    try:
        repeats: list[_Repeated] = []
        data = json.loads(text, object_pairs_hook=lambda pairs: _object(pairs, repeats), parse_int=_integer)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SpecError(f"{what} is not valid JSON: {exc}") from exc
    except ValueError as exc:
        raise SpecError(f"{what} holds a number Dyana cannot read: {shorten(str(exc), 160)}") from None
    except RecursionError:
        raise SpecError(f"{what} JSON is nested too deeply") from None
    path = _repeated_key(what, data) if repeats else None
    if path is not None:
        raise FieldError(path, "is given twice (a key may appear once in a JSON object)")
    return data
