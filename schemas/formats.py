"""The storage formats a build or run writes: Parquet always, MCAP unless left out."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from schemas.errors import SpecError
from schemas.names import shorten

ALL_FORMATS = ("parquet", "mcap")


def parse_formats(value: str | Sequence[str]) -> tuple[str, ...]:
    """``"parquet,mcap"`` (or a sequence) as a tuple in canonical order; Parquet is required
    because every reader (the dataloader, scoring, verify) reads the tables."""
    if not isinstance(value, (str, list, tuple)):
        raise SpecError(f"--formats takes a comma-separated subset of {','.join(ALL_FORMATS)} (or a list), "
                        f"got {shorten(repr(value), 60)}")
    names = [part.strip() for part in value.split(",")] if isinstance(value, str) else list(value)
    unknown = [name for name in names if not isinstance(name, str) or name not in ALL_FORMATS]
    if unknown or not names:
        shown = repr(str(unknown[0])[:40]) if unknown else "nothing"
        raise SpecError(f"--formats takes a comma-separated subset of {','.join(ALL_FORMATS)}, got {shown}")
    if "parquet" not in names:
        raise SpecError(f"--formats must include parquet (the tables every reader uses), got {','.join(names)[:60]!r}")
    return tuple(name for name in ALL_FORMATS if name in names)


def stored_formats(settings: Mapping[str, Any]) -> tuple[str, ...]:
    """The formats a manifest's settings say were written (both before settings recorded them)."""
    value = settings.get("formats", list(ALL_FORMATS))
    if not isinstance(value, list) or tuple(value) != parse_formats(value):
        raise SpecError(f"settings.formats must be a list such as {list(ALL_FORMATS)}, got {value!r}"[:160])
    return tuple(value)
