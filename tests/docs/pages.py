"""Reading the executable blocks of README.md and docs/**/*.md.

A page is a list of :class:`Block` in page order: fenced ``bash`` and ``python`` blocks,
each with the marker written on the line right before its fence
(``<!-- docs-test: slow -->``, ``<!-- docs-test: needs MODULE -->`` or
``<!-- docs-test: skip REASON -->``), plus the page's ``<!-- docs-setup: COMMAND -->``
commands. ``text`` (and any other language) blocks are output and are not run.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RUN_LANGUAGES = ("bash", "python")
MARKER = re.compile(r"^\s*<!--\s*docs-test:\s*(?P<body>.*?)\s*-->\s*$")
SETUP = re.compile(r"<!--\s*docs-setup:\s*(?P<command>.*?)\s*-->")
FENCE = re.compile(r"^(?P<indent>\s*)(?P<fence>`{3,}|~{3,})\s*(?P<info>[^`\s]*)")
#: The marker words a page may use (anything else is a typo and fails the marker test).
MARKER_KINDS = ("slow", "needs", "skip")


@dataclass(frozen=True)
class Marker:
    """``slow``, ``needs MODULE`` or ``skip REASON`` (``argument`` is the module or reason);
    a slow block that needs a module says so first: ``slow needs MODULE (covered by ...)``."""

    kind: str
    argument: str = ""

    @classmethod
    def parse(cls, body: str) -> Marker:
        kind, _, argument = body.strip().partition(" ")
        return cls(kind, argument.strip())

    @property
    def module(self) -> str | None:
        """The module the block needs (skipped where it is not importable), if any."""
        if self.kind == "needs":
            return self.argument or None
        if self.kind == "slow" and self.argument.startswith("needs "):
            return self.argument.split()[1]
        return None

    @property
    def cover(self) -> str:
        """A slow marker's ``(covered by ...)``, after its module if it names one."""
        return self.argument.split(None, 2)[2] if self.kind == "slow" and self.module else self.argument


@dataclass(frozen=True)
class Block:
    """One fenced block to run: its page, the line of its opening fence (1-based), language, code."""

    page: str
    line: int
    language: str
    code: str
    marker: Marker | None = None

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"


@dataclass(frozen=True)
class Page:
    path: str
    blocks: tuple[Block, ...]
    setup: tuple[str, ...]

    @property
    def has_slow(self) -> bool:
        return any(b.marker is not None and b.marker.kind == "slow" for b in self.blocks)


def parse(path: str, text: str) -> Page:
    """Every fenced block of a page with its marker, and the page's setup commands."""
    lines = text.splitlines()
    blocks: list[Block] = []
    setup: list[str] = []
    i = 0
    while i < len(lines):
        match = FENCE.match(lines[i])
        if not match:
            setup += [m.group("command") for m in SETUP.finditer(lines[i])]
            i += 1
            continue
        fence, language, start = match.group("fence"), match.group("info").lower(), i
        i += 1
        body = []
        while i < len(lines) and not lines[i].strip().startswith(fence):
            body.append(lines[i])
            i += 1
        i += 1  # the closing fence
        if language in RUN_LANGUAGES:
            marker_line = MARKER.match(lines[start - 1]) if start > 0 else None
            marker = Marker.parse(marker_line.group("body")) if marker_line else None
            indent = len(match.group("indent"))
            code = "\n".join(line[indent:] if line[:indent].isspace() else line for line in body) + "\n"
            blocks.append(Block(path, start + 1, language, code, marker))
    return Page(path, tuple(blocks), tuple(setup))


def page_paths(root: Path = ROOT) -> list[str]:
    """README.md, then docs/**/*.md in name order (paths relative to the repository)."""
    docs = sorted(p.relative_to(root).as_posix() for p in (root / "docs").rglob("*.md"))
    return ["README.md", *docs]


def load(path: str, root: Path = ROOT) -> Page:
    return parse(path, (root / path).read_text(encoding="utf-8"))
