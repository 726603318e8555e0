"""Write-then-rename: a file appears under its final name only once it is complete.

A file in progress lives beside its destination as ``.<name>.tmp-<pid>`` (same
directory, so the rename stays on one file system and is atomic). Completing it
flushes and fsyncs the data, renames it over the destination and fsyncs the
directory; abandoning it deletes it. A crashed build leaves only such temp names,
which :func:`find_stray_temps` lists and :func:`remove_stray_temps` clears.
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO, Literal, TextIO, TypeVar, overload

TEMP_PATTERN = re.compile(r"^\.(?P<name>.+)\.tmp-(?P<pid>\d+)$")


def temp_path(path: str | os.PathLike[str], pid: int | None = None) -> Path:
    """The temporary name ``.<name>.tmp-<pid>`` of ``path``, in the same directory."""
    final = Path(path)
    return final.with_name(f".{final.name}.tmp-{os.getpid() if pid is None else pid}")


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # some platforms cannot open directories; the rename is still atomic
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def commit(temp: str | os.PathLike[str], final: str | os.PathLike[str]) -> None:
    """fsync ``temp``, rename it to ``final`` (replacing it) and fsync the directory."""
    temp, final = Path(temp), Path(final)
    with open(temp, "rb+") as handle:
        os.fsync(handle.fileno())
    os.replace(temp, final)
    _fsync_dir(final.parent)


def discard(temp: str | os.PathLike[str]) -> None:
    """Delete a temporary file if it exists."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(temp)


Handle = TypeVar("Handle", BinaryIO, TextIO)


@contextlib.contextmanager
def _write_then_rename(path: str | os.PathLike[str], open_temp: Callable[[Path], Handle]) -> Iterator[Handle]:
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    temp = temp_path(final)
    try:
        with open_temp(temp) as handle:
            yield handle
            handle.flush()
        commit(temp, final)
    except BaseException:
        discard(temp)
        raise


@overload
def atomic_open(path: str | os.PathLike[str], mode: Literal["wb"] = "wb") -> contextlib.AbstractContextManager[BinaryIO]: ...


@overload
def atomic_open(path: str | os.PathLike[str], mode: Literal["w"]) -> contextlib.AbstractContextManager[TextIO]: ...


def atomic_open(
    path: str | os.PathLike[str], mode: str = "wb"
) -> contextlib.AbstractContextManager[BinaryIO] | contextlib.AbstractContextManager[TextIO]:
    """Open ``path``'s temp name for writing (``wb``, or ``w``: UTF-8 with ``\\n`` line ends);
    on success commit it, on error delete it."""
    if mode == "wb":
        return _write_then_rename(path, lambda temp: open(temp, "wb"))
    if mode == "w":
        return _write_then_rename(path, lambda temp: open(temp, "w", encoding="utf-8", newline="\n"))
    raise ValueError(f"atomic_open writes only, mode must be 'wb' or 'w', got {mode!r}")


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write UTF-8 ``text`` (``\\n`` line ends) to ``path`` atomically; returns the path."""
    with atomic_open(path, "w") as handle:
        handle.write(text)
    return Path(path)


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    except OSError:
        return False
    return not _is_zombie(pid)


def _is_zombie(pid: int) -> bool:
    """A killed writer whose parent never reaped it still answers ``kill(pid, 0)``."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[-1].split()[0] in ("Z", "X")


def find_stray_temps(directory: str | os.PathLike[str], recursive: bool = True) -> list[Path]:
    """Temp files (``.<name>.tmp-<pid>``) under ``directory``, sorted."""
    root = Path(directory)
    if not root.is_dir():
        return []
    candidates = root.rglob(".*.tmp-*") if recursive else root.glob(".*.tmp-*")
    return sorted(p for p in candidates if p.is_file() and TEMP_PATTERN.match(p.name))


def remove_stray_temps(directory: str | os.PathLike[str], *, only_dead: bool = True,
                       keep_own: bool = True) -> list[Path]:
    """Delete temp files left by builds that died; returns what was removed.

    With ``only_dead`` (the default) a temp file whose writer pid is still running on
    this host is kept, so a concurrent build is not disturbed. Pids are host-local:
    on a shared file system written from several hosts, pass ``only_dead=False`` only
    when no build is running. ``keep_own=False`` also removes temps named with this
    process's pid: for a caller that holds the folder's lock and has written nothing yet
    (such a temp is a dead writer's whose pid was reused).
    """
    removed = []
    for path in find_stray_temps(directory):
        match = TEMP_PATTERN.match(path.name)
        if match is None:  # find_stray_temps lists only matching names
            continue
        pid = int(match["pid"])
        if only_dead and not (pid == os.getpid() and not keep_own) and _pid_alive(pid):
            continue
        discard(path)
        removed.append(path)
    return removed
