"""Where a shard task writes its files, described so that a worker on any host can open it.

A :class:`ShardSink` is the job's output location as text: the absolute path of a local
folder (on one machine, or a filesystem every host mounts at that same path), or an
object-store URL (``s3://bucket/prefix/slice``). It is what the driver sends with every
task instead of a folder of its own, so a Dask worker on another machine writes where the
job's output is, never into a path that exists only on the driver.

A task writes its shard through :meth:`ShardSink.writing`, which yields a local folder:

- a local sink yields the folder itself (files written under temporary names, then
  renamed: :mod:`catalog.store.atomic`), exactly as before sinks existed;
- a URL sink yields a private scratch folder on the worker's own disk (under ``TMPDIR``);
  once the task's writing succeeded each file is uploaded as one object (an object store
  shows an object whole or not at all), then the scratch folder is removed. A task that
  fails or is killed uploads nothing more; objects it already uploaded are whole files
  that no record lists yet (:mod:`pipeline.jobs.object_store` says when a shard counts).

Credentials and the endpoint are never part of a sink: each host's worker processes read
their own (``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_ENDPOINT_URL`` in their
environment, or the client's config files), so no secret travels through the scheduler.
Before a URL task does any work it checks the store writable from its host, so a worker
without credentials fails its task at once, as one StorageError naming the URL.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from catalog.store.atomic import TEMP_PATTERN
from catalog.store.storage import as_location, check_writable, is_url, reaching
from schemas.errors import SpecError
from schemas.names import shorten


@dataclass(frozen=True)
class ShardSink:
    """A job's output location as a task receives it: an absolute local path or a URL."""

    location: str

    def __post_init__(self) -> None:
        if not isinstance(self.location, str) or not self.location:
            raise SpecError(f"a shard sink's location must be a non-empty path or URL, got {shorten(repr(self.location))}")
        if not is_url(self.location) and not os.path.isabs(self.location):
            raise SpecError(f"a shard sink's folder must be an absolute path (a worker's working folder "
                            f"differs from the driver's), got {self.location[:80]!r}")

    @classmethod
    def folder(cls, folder: str | os.PathLike[str]) -> ShardSink:
        """The sink of a local folder (made absolute)."""
        return cls(os.path.abspath(folder))

    @property
    def remote(self) -> bool:
        return is_url(self.location)

    @contextlib.contextmanager
    def writing(self) -> Iterator[Path]:
        """The local folder a task writes its shard files into (see the module docstring)."""
        if not self.remote:
            yield Path(self.location)
            return
        remote = as_location(self.location)
        check_writable(remote)
        scratch = Path(tempfile.mkdtemp(prefix="dyana-shard-"))
        try:
            yield scratch
            root = remote.path.rstrip("/")  # type: ignore[attr-defined]
            with reaching(self.location):
                for path in sorted(p for p in scratch.rglob("*") if p.is_file() and not TEMP_PATTERN.match(p.name)):
                    remote.fs.put_file(os.fspath(path), f"{root}/{path.relative_to(scratch).as_posix()}")  # type: ignore[attr-defined]
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
