"""The protocols `pipeline serve --protocol` speaks: a name -> the maker of its :class:`Wire`
from the ``--openpi-key NAME=KEY`` settings. The command line's ``--protocol`` choices are
this table's names; each maker imports its server code when called, so reading the names
costs the parser nothing."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from schemas.errors import SpecError

if TYPE_CHECKING:
    from pipeline.remote.serve import Wire


def _dyana(settings: Sequence[tuple[str, str]]) -> Wire:
    from pipeline.remote.serve import DYANA

    if settings:
        raise SpecError("--openpi-key is for --protocol openpi")
    return DYANA


def _openpi(settings: Sequence[tuple[str, str]]) -> Wire:
    from pipeline.remote.openpi_serve import openpi_wire_for

    return openpi_wire_for(settings)


PROTOCOLS: dict[str, Callable[[Sequence[tuple[str, str]]], Wire]] = {"dyana": _dyana, "openpi": _openpi}


def wire_for(name: str, settings: Sequence[tuple[str, str]] = ()) -> Wire:
    """The wire called ``name``; SpecError for an unknown one or settings it does not take."""
    if name not in PROTOCOLS:
        raise SpecError(f"unknown protocol {name!r:.40} (known: {', '.join(PROTOCOLS)})")
    return PROTOCOLS[name](list(settings))
