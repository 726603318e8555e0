"""Files a user names for output (``scoring eval --csv/--markdown/--episodes/--plot``,
``pipeline view --out``): written whole or not at all, never over something that is not a
file, never into a folder being read.

What the path is decides how it is written (symlinks followed):

- absent or a regular file: written beside it under a temp name and renamed over it
  (:func:`catalog.store.atomic.atomic_open`), so a reader sees the old file or the new one; a
  symlink is kept and the file it points to is replaced;
- a character device or a FIFO (``/dev/null``, a terminal, a named pipe, ``/dev/stdout``):
  opened and written as such, never renamed over (``/dev/null`` stays a device); so is an
  alias of an open descriptor (``/dev/stdout`` redirected to a file is appended to); a
  missing name directly in ``/dev`` (a typo of a device) is refused;
- a folder, socket or block device (or a symlink to one): refused, one line naming it;
- a path that resolves inside a folder being read (``run/catalog.json`` while scoring
  ``run``): refused, naming both.

Refusals are :class:`~schemas.errors.OutputError` and come from :func:`check_output`,
which a command calls for every output before any work. :func:`open_output` writes
through a handle; :func:`staged_output` gives a library that wants a file name (rerun) a
temp name and puts the result in place by the same rule.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO

from catalog.store.atomic import atomic_open, commit, discard, temp_path
from catalog.store.storage import is_remote, is_url
from schemas.errors import OutputError
from schemas.names import shorten

#: Aliases of open descriptors (``/dev/stdout``, ``/dev/fd/3``, ``/proc/self/fd/1``): written
#: in place (appended to) whatever they resolve to, as a shell redirect expects.
DESCRIPTOR_ALIAS = re.compile(r"^(/dev/(stdout|stderr|tty|fd/\d+)|/proc/(self|\d+)/fd/\d+)$")
#: File types refused as an output, by name for the message.
REFUSED = {stat.S_IFDIR: "a folder", stat.S_IFSOCK: "a socket", stat.S_IFBLK: "a block device"}


def _named(path: str | os.PathLike[str], flag: str | None) -> str:
    text = shorten(repr(os.fspath(path)))
    return f"{flag} {text}" if flag else text


def _in_place(path: str, mode: int | None) -> bool:
    """True for a device or FIFO, or a descriptor alias (:data:`DESCRIPTOR_ALIAS`)."""
    if mode is not None and (stat.S_ISCHR(mode) or stat.S_ISFIFO(mode)):
        return True
    return DESCRIPTOR_ALIAS.match(os.path.abspath(path)) is not None


def _mode(path: str) -> int | None:
    """The st_mode of what ``path`` points to, None when nothing is there yet."""
    try:
        return os.stat(path).st_mode
    except FileNotFoundError:
        return None
    except NotADirectoryError:
        raise OutputError(f"{shorten(repr(path))}: a part of the path is a file, not a folder") from None
    except OSError as exc:
        raise OutputError(f"{shorten(repr(path))}: cannot write: {exc.strerror or exc}") from None


def check_output(
    path: str | os.PathLike[str],
    inputs: Iterable[str | os.PathLike[str]] = (),
    flag: str | None = None,
) -> None:
    """OutputError unless ``path`` may be written by :func:`open_output`: not empty, not a
    folder, socket or block device, and not inside any local folder of ``inputs``
    (after resolving symlinks). ``flag`` (e.g. ``"--csv"``) prefixes the message."""
    text = os.fspath(path)
    if not isinstance(text, str):
        raise OutputError(f"{flag or 'output'}: the path must be text, got {shorten(repr(text))}")
    if not text:
        raise OutputError(f"{flag or 'output'}: the path is empty (give a file name)")
    if is_url(text):  # else a local folder named "s3:" would be made
        raise OutputError(f"{_named(text, flag)}: is a URL; this output is a local file (write it here, then copy it)")
    kind = _mode(text)
    if kind is not None and stat.S_IFMT(kind) in REFUSED:
        raise OutputError(f"{_named(text, flag)} is {REFUSED[stat.S_IFMT(kind)]}, not a file: give a file name")
    if kind is None and (os.path.dirname(os.path.abspath(text)) == "/dev" or _in_place(text, kind)):
        raise OutputError(f"{_named(text, flag)}: no such device or descriptor")
    if _in_place(text, kind):
        return
    target = os.path.realpath(text)
    for folder in inputs:
        if is_remote(folder):
            continue
        root = os.path.realpath(os.fspath(folder))
        if target == root or target.startswith(root.rstrip(os.sep) + os.sep):
            raise OutputError(
                f"{_named(text, flag)} lies inside {shorten(repr(os.fspath(folder)))}, which is being read: "
                "write it elsewhere"
            )


@contextlib.contextmanager
def open_output(
    path: str | os.PathLike[str],
    mode: str = "w",
    inputs: Iterable[str | os.PathLike[str]] = (),
    flag: str | None = None,
) -> Iterator[IO]:
    """``path`` open for writing (``mode`` ``"w"``, UTF-8, or ``"wb"``) by the rule of this
    module: a file is complete under its name only when the block ends without error."""
    if mode not in ("w", "wb"):
        raise ValueError(f"open_output writes only, mode must be 'w' or 'wb', got {mode!r}")
    check_output(path, inputs, flag)
    text = os.fspath(path)
    if _in_place(text, _mode(text)):
        sys.stdout.flush()  # what was printed before comes first on a shared terminal or pipe
        fd = os.open(text, os.O_WRONLY | os.O_APPEND)
        handle: IO = open(fd, "w", encoding="utf-8", newline="\n") if mode == "w" else open(fd, "wb")
        with handle:
            yield handle
        return
    target = os.path.realpath(text)
    if mode == "w":
        with atomic_open(target, "w") as text_handle:
            yield text_handle
    else:
        with atomic_open(target, "wb") as binary_handle:
            yield binary_handle


@contextlib.contextmanager
def staged_output(
    path: str | os.PathLike[str],
    inputs: Iterable[str | os.PathLike[str]] = (),
    flag: str | None = None,
) -> Iterator[Path]:
    """A temp file name for a library that writes to a name (rerun's ``save``); when the block
    ends without error its content is put at ``path`` by :func:`place`, else it is deleted.
    The temp lies beside the file ``path`` resolves to, or in the system's temp folder for
    a device or FIFO (never in ``/dev``)."""
    check_output(path, inputs, flag)
    text = os.fspath(path)
    if _in_place(text, _mode(text)):
        handle, name = tempfile.mkstemp(prefix="dyana-output-")
        os.close(handle)
        temp = Path(name)
    else:
        temp = temp_path(os.path.realpath(text))
        temp.parent.mkdir(parents=True, exist_ok=True)
    try:
        yield temp
    except BaseException:
        discard(temp)
        raise
    place(temp, path, flag)


def place(temp: str | os.PathLike[str], path: str | os.PathLike[str], flag: str | None = None) -> None:
    """Put a finished ``temp`` file (written by a library that wants a file name, e.g. rerun)
    at ``path`` by the rule of this module: renamed over the file ``path`` resolves to (the
    temp must be in its folder, as :func:`staged_output` makes it), or copied into a device
    or FIFO and deleted."""
    check_output(path, flag=flag)
    text = os.fspath(path)
    try:
        if _in_place(text, _mode(text)):
            with open(temp, "rb") as source, open_output(path, "wb", flag=flag) as handle:
                shutil.copyfileobj(source, handle)
        else:
            commit(temp, os.path.realpath(text))
    finally:
        discard(temp)
