"""The folder lock: one job writes (or checks) a folder at a time.

The lock is ``filelock``'s (the kernel's ``flock`` on ``FOLDER/.lock``), so a killed holder
releases it. The file stays in the folder after a run: removing a lock file while it is
held lets a second process lock a new file of the same name while the first still holds
the old one (both "hold the lock"). ``.lock`` is no shard, part or metadata file: no
manifest lists it, no hash covers it, and the readers and checks skip it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from filelock import FileLock, Timeout

from schemas.errors import DyanaError

LOCK_FILE = ".lock"


class FolderBusy(DyanaError):
    """Another process holds the folder's lock."""


@contextlib.contextmanager
def held(path: Path, what: str) -> Iterator[None]:
    """Hold the lock file ``path`` for the duration; FolderBusy at once, naming ``what``
    (the folder or URL being written), if another holder has it."""
    lock = FileLock(path, timeout=0)
    try:
        lock.acquire()
    except Timeout:
        raise FolderBusy(f"{what}: another process is writing this folder (lock {path} is held)") from None
    try:
        yield
    finally:
        lock.release()


def folder_lock(folder: Path) -> contextlib.AbstractContextManager[None]:
    """Hold ``folder/.lock`` for the duration (FolderBusy at once if another holder has it)."""
    return held(folder / LOCK_FILE, str(folder))
