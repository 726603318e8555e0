"""Plain-text tables for the terminal: aligned columns, and wide tables packed into
several that each fit a terminal's width, the row labels repeated in each, so that no
line runs past :data:`WIDTH` columns however many metrics a table has."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence

#: The widest line ``scoring eval`` prints (a terminal, a paper's appendix in monospace).
WIDTH = 100


def aligned(headers: Sequence[str], rows: Sequence[Sequence[str]], text_columns: int = 1) -> str:
    """Text columns left-aligned, numbers right-aligned, two spaces apart."""
    widths = [max(len(str(c)) for c in column) for column in zip(headers, *rows)]

    def line(cells: Sequence[str]) -> str:
        padded = [str(c).ljust(w) if i < text_columns else str(c).rjust(w) for i, (c, w) in enumerate(zip(cells, widths))]
        return "  ".join(padded).rstrip()

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([line(headers), rule, *(line(r) for r in rows)])


def packed(headers: Sequence[str], rows: Sequence[Sequence[str]], lead: int, groups: Sequence[Sequence[int]],
           width: int = WIDTH) -> str:
    """``aligned`` tables of the first ``lead`` columns (the row labels, repeated) and as many
    of the column ``groups`` (a metric with its interval, kept together) as fit in ``width``;
    a group wider than the width alone gets a table of its own."""
    widths = [max(len(str(c)) for c in column) for column in zip(headers, *rows)]
    lead_width = sum(widths[:lead]) + 2 * lead
    tables: list[list[int]] = []
    used = width  # start a new table at the first group
    for group in groups:
        need = sum(widths[i] + 2 for i in group)
        if used + need > width and (not tables or tables[-1]):
            tables.append([])
            used = lead_width
        tables[-1].extend(group)
        used += need
    parts = []
    for columns in tables:
        keep = list(range(lead)) + columns
        parts.append(aligned([headers[i] for i in keep], [[row[i] for i in keep] for row in rows], text_columns=lead))
    return "\n\n".join(parts)


def wrapped(text: str, width: int = WIDTH) -> str:
    """A note as lines of at most ``width`` columns."""
    return "\n".join(textwrap.wrap(text, width=width, break_on_hyphens=False))
