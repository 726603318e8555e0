"""The protocols `pipeline serve --protocol` speaks: a name -> the maker of its :class:`Wire`
from the ``--openpi-key NAME=KEY`` settings."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from pipeline.remote.openpi_serve import openpi_wire_for
from pipeline.remote.serve import DYANA, Wire
from schemas.errors import SpecError


def _dyana(settings: Sequence[tuple[str, str]]) -> Wire:
    if settings:
        raise SpecError("--openpi-key is for --protocol openpi")
    return DYANA


PROTOCOLS: dict[str, Callable[[Sequence[tuple[str, str]]], Wire]] = {"dyana": _dyana, "openpi": openpi_wire_for}


def wire_for(name: str, settings: Sequence[tuple[str, str]] = ()) -> Wire:
    """The wire called ``name``; SpecError for an unknown one or settings it does not take."""
    if name not in PROTOCOLS:
        raise SpecError(f"unknown protocol {name!r:.40} (known: {', '.join(PROTOCOLS)})")
    return PROTOCOLS[name](list(settings))
