"""Opening a file named from outside (a specs file, a folder's ``catalog.json``) only if it
is a regular file.

A FIFO in its place would block the reader for ever, and a link to a device such as
``/dev/zero`` would stream without end. So the file is opened without blocking (a FIFO
opens at once) and its kind is read from the open descriptor, before any byte is read.
"""

from __future__ import annotations

import os
import stat
from typing import BinaryIO

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"))


def file_kind(mode: int) -> str:
    """What a file of this ``st_mode`` is, for a message (``"a FIFO"``, ``"a folder"``, ...)."""
    if stat.S_ISREG(mode):
        return "a regular file"
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def open_regular(path: str | os.PathLike[str]) -> tuple[BinaryIO | None, os.stat_result]:
    """``path`` open for binary reading, and its status; the handle is None (and nothing is
    left open) when it is not a regular file: :func:`file_kind` of the status names it.
    OSError as ``os.open`` raises it (a missing file, no permission)."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    status = os.fstat(fd)
    if not stat.S_ISREG(status.st_mode):
        os.close(fd)
        return None, status
    return os.fdopen(fd, "rb"), status
