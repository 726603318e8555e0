"""A folder of repeats, as ``pipeline eval --repeats K`` writes it: ``DIR/repeats.json``
naming one ordinary run folder per repeat (``DIR/repeat-00``, ...). ``scoring eval DIR``
reads them together; every other reader opens one run, so a folder of repeats given to
one is refused saying what it is and what to pass instead (:func:`repeats_hint`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from catalog.store.storage import as_location
from schemas.errors import SpecError

REPEATS_FILE = "repeats.json"


def repeat_folders(root: Path) -> list[Path]:
    """The repeat folders ``root/repeats.json`` names (each a plain folder name inside ``root``)."""
    path = root / REPEATS_FILE
    try:
        names = [entry["path"] for entry in json.loads(path.read_text())["runs"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SpecError(f"{path}: not a readable repeats index ({type(exc).__name__})") from None
    for name in names:
        if not isinstance(name, str) or "/" in name or "\\" in name or name in ("", ".", ".."):
            raise SpecError(f"{path}: a repeat's path must be a folder name, got {str(name)[:60]!r}")
    return [root / name for name in names]


def repeats_hint(directory: str | os.PathLike[str]) -> str | None:
    """When ``directory`` is a folder of repeats: one line saying so, naming its repeats and
    one to pass instead; otherwise None."""
    root = as_location(directory)
    try:
        if not (root / REPEATS_FILE).is_file():
            return None
    except OSError:
        return None
    try:
        folders = repeat_folders(root)
    except SpecError as exc:
        return f"{root} is a folder of repeats, but {exc}"
    if not folders:
        return f"{root} is a folder of repeats ({REPEATS_FILE}) that names none"
    names = folders[0].name if len(folders) == 1 else f"{folders[0].name} ... {folders[-1].name}"
    count = f"{len(folders)} repeat{'s' if len(folders) != 1 else ''}"
    return (f"{root} is a folder of {count} ({names}, indexed by {REPEATS_FILE}), not one run: "
            f"pass one of them, e.g. {folders[0]} (`scoring eval {root}` scores them together)")
