"""The command-line reference page, generated from the argparse parsers themselves.

Every console script named in pyproject.toml's ``[project.scripts]`` is asked for its parser
(its ``main`` is called with ``parse_args`` intercepted, so nothing runs), and each
subcommand's usage, help and options are written out. Nothing here is typed by hand: a
new flag or command appears on the page at the next build.
"""

from __future__ import annotations

import argparse
import importlib
import os
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from unittest import mock

#: Usage lines are wrapped at this width, whatever the terminal building the site.
WIDTH = 100


class _Captured(Exception):
    def __init__(self, parser: argparse.ArgumentParser) -> None:
        super().__init__(parser.prog)
        self.parser = parser


def console_scripts(root: Path) -> dict[str, str]:
    """``{program: "module:function"}`` from pyproject.toml, in its order."""
    with open(root / "pyproject.toml", "rb") as f:
        return dict(tomllib.load(f)["project"]["scripts"])


def parser_of(entry: str) -> argparse.ArgumentParser:
    """The top-level parser a console script's ``main`` builds (``main`` does not run)."""
    module_name, _, function = entry.partition(":")
    main = getattr(importlib.import_module(module_name), function)

    def capture(self: argparse.ArgumentParser, *args: object, **kwargs: object) -> None:
        raise _Captured(self)

    import schemas.cli

    with mock.patch.object(argparse.ArgumentParser, "parse_args", capture), \
            mock.patch.object(schemas.cli, "FOR_THE_SITE", True):  # no "2 here" from the docs machine
        try:
            main([])
        except _Captured as captured:
            return captured.parser
    raise RuntimeError(f"{entry} returned without parsing its arguments")


def subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """``(name, help, parser)`` of each subcommand, in declaration order."""
    out = []
    for action in parser._actions:  # argparse has no public API for its subparsers
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help or "" for choice in action._choices_actions}
            out += [(name, helps.get(name, ""), sub) for name, sub in action.choices.items()]
    return out


@contextmanager
def _columns(width: int) -> Iterator[None]:
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width + 2)
    try:
        yield
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


def _cell(text: str, code: bool = False) -> str:
    """One table cell: whitespace joined, ``|`` escaped and, outside a code span, ``<``/``>`` as
    entities (``OUT/<slice>/`` would otherwise be read as an HTML tag and vanish)."""
    cell = " ".join(text.split()).replace("|", "\\|")
    return cell if code else cell.replace("<", "&lt;").replace(">", "&gt;")


def _help(action: argparse.Action, prog: str) -> str:
    text = action.help or ""
    if "%(" in text:
        params = {**vars(action), "prog": prog, "default": action.default}
        text = text % params
    return text


def arguments(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The arguments ``--help`` lists (the subcommand choice excluded)."""
    return [a for a in parser._actions
            if a.help != argparse.SUPPRESS and not isinstance(a, argparse._SubParsersAction)]


def _option_rows(parser: argparse.ArgumentParser) -> list[str]:
    rows = []
    for action in arguments(parser):
        if action.option_strings:
            takes_value = action.nargs != 0
            metavar = action.metavar or action.dest.upper()
            names = ", ".join(f"{o} {metavar}" if takes_value else o for o in action.option_strings)
        else:
            names = str(action.metavar or action.dest)
        rows.append(f"| `{_cell(names, code=True)}` | {_cell(_help(action, parser.prog))} |")
    return rows


def _parser_section(parser: argparse.ArgumentParser, heading: str, help_text: str) -> list[str]:
    with _columns(WIDTH):
        usage = parser.format_usage().strip()
    lines = [heading, ""]
    if help_text:
        lines += [help_text[0].upper() + help_text[1:] + ("" if help_text.endswith(".") else "."), ""]
    lines += ["```text", usage, "```", ""]
    rows = _option_rows(parser)
    if rows:
        lines += ["| argument | meaning |", "|---|---|", *rows, ""]
    return lines


def render(root: Path) -> str:
    """The whole page, as Markdown."""
    scripts = console_scripts(root)
    lines = [
        "# Command reference",
        "",
        "Generated when the site is built, from the parsers of the console scripts ("
        + ", ".join(f"`{name}`" for name in scripts)
        + "): what `--help` prints, one section per subcommand. Every command and subcommand "
        "takes `--help` and `--version`; errors are one line on stderr and exit 2 "
        "(see [bad input](bad-input.md)).",
        "",
    ]
    for program, entry in scripts.items():
        parser = parser_of(entry)
        commands = subcommands(parser)
        lines += [f"## {program}", ""]
        if parser.description:
            lines += [parser.description, ""]
        if commands:
            lines += ["| command | what it does |", "|---|---|"]
            lines += [f"| [`{program} {name}`](#{program}-{name}) | {_cell(text)} |" for name, text, _ in commands]
            lines += [""]
        for name, text, sub in commands:
            lines += _parser_section(sub, f"### {program} {name}", text)
    return "\n".join(lines).rstrip() + "\n"
