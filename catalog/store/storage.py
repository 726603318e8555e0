"""Where a folder lives: a local path, or an object-store URL (``s3://bucket/prefix``) read
and written through fsspec.

A URL becomes a :class:`upath.UPath` (pathlib's API over an fsspec filesystem), so the
readers' path arithmetic (``root / "frames/000000-000127.parquet"``, ``stat().st_size``,
``read_text()``) is the same for both. Credentials and the endpoint come from the
environment (``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_ENDPOINT_URL``
for an S3-compatible server, as botocore reads them), or from a UPath given in code
(``UPath(url, key=..., secret=..., endpoint_url=...)``), whose options every path derived
from it keeps; nothing about them is written anywhere. Files are opened for ranged reads
(a small read-ahead cache), never downloaded whole unless every byte is needed (a sha256).

The client's failures (no credentials, an unreachable endpoint, a refused request) become
one :class:`~schemas.errors.StorageError` naming the URL (:func:`reaching`); an output URL
is checked writable before any work (:func:`check_writable`).
"""

from __future__ import annotations

import os
import re
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

from schemas.errors import ShardError, SpecError, StorageError
from schemas.names import printable, shorten
from schemas.storage_faults import describe_storage_fault, is_storage_fault

_URL = re.compile(r"^([a-z][a-z0-9+.-]*)://", re.IGNORECASE)
#: Bytes fetched per ranged read when a remote file is walked (Parquet page headers).
READ_AHEAD = 64 * 1024
#: botocore's client timeouts for a URL Dyana opens (its defaults are 60 s each): an endpoint
#: that accepts and never answers fails after its attempts (AWS_MAX_ATTEMPTS, botocore's
#: default 5) of 10 s each, not never. An S3 URL's requests are also bounded in all
#: (:mod:`catalog.store.s3_session`), so one that trickles bytes is cut too.
CLIENT_TIMEOUTS = {"connect_timeout": 5, "read_timeout": 10}


def client_options(scheme: str) -> dict[str, Any]:
    """The fsspec options of a URL Dyana opens: for S3 (s3fs) the client's timeouts and the
    bounded session; none for other schemes (their file systems take other options)."""
    if scheme.lower() not in ("s3", "s3a"):
        return {}
    config: dict[str, Any] = dict(CLIENT_TIMEOUTS)
    try:
        from catalog.store.s3_session import BoundedSession
    except ImportError:  # no aiobotocore: s3fs itself will say what is missing
        return {"config_kwargs": config}
    config["http_session_cls"] = BoundedSession
    return {"config_kwargs": config}


def is_url(location: Any) -> bool:
    """True for a string ``scheme://...`` other than ``file://``."""
    match = _URL.match(location) if isinstance(location, str) else None
    return match is not None and match.group(1).lower() != "file"


def as_location(location: str | os.PathLike[str], name: str = "path") -> Path:
    """A local :class:`~pathlib.Path`, or a :class:`upath.UPath` for a URL (a Path subclass);
    SpecError naming ``name`` (the caller's argument) for anything else: not a str or
    path-like (None, a number, bytes), an empty name (``--out "$UNSET"``: not the current
    folder), or a name with a NUL byte no file system takes."""
    if isinstance(location, Path) or (not isinstance(location, str) and is_remote(location)):
        return location  # type: ignore[return-value]
    text = location if isinstance(location, str) else os.fspath(location) if isinstance(location, os.PathLike) else None
    if not isinstance(text, str) or not text or "\x00" in text:
        raise SpecError(f"{name} must be a folder or file name (str or path-like), got {shorten(repr(location))}")
    if is_url(location):
        try:
            from upath import UPath
        except ImportError:
            raise ShardError(f"{str(location)[:80]}: object storage needs universal-pathlib and s3fs "
                             "(pip install 'dyana[s3]')") from None
        if not str(location).split("://", 1)[1].split("/", 1)[0]:
            raise SpecError(f"{name}: {printable(repr(location))} names no bucket (expected e.g. s3://bucket/folder)")
        if "//" in str(location).split("://", 1)[1].rstrip("/") or not str(location).isprintable():
            # s3://bucket//x writes keys under "/x/": a folder no reader finds again
            raise SpecError(f"{name}: {printable(repr(location))} has an empty folder name or a control character")
        try:
            path = UPath(str(location), **client_options(str(location).split("://", 1)[0]))
            path.fs  # noqa: B018  # the file system's class: an uninstalled one (gs:// without gcsfs) fails here
        except (ValueError, ImportError) as exc:
            raise ShardError(f"{str(location)[:80]}: not a storage URL this installation reads ({exc})") from None
        return path
    return Path(location)


def is_remote(path: Any) -> bool:
    """True for a location that is not on the local filesystem."""
    if isinstance(path, str):
        return is_url(path)
    protocol = getattr(path, "protocol", None)
    return isinstance(protocol, str) and protocol not in ("", "file", "local")


def open_binary(path: str | os.PathLike[str]) -> BinaryIO:
    """``path`` opened for reading bytes (a ranged-read file object for a remote path)."""
    path = as_location(path)
    if is_remote(path):
        return path.fs.open(path.path, "rb", block_size=READ_AHEAD, cache_type="readahead")  # type: ignore[attr-defined]
    return open(path, "rb")


class RangeReader:
    """``os.pread``'s contract over a remote file: ``pread(length, offset)`` is one ranged request."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def pread(self, length: int, offset: int) -> bytes:
        if length <= 0:
            return b""
        return self.path.fs.cat_file(self.path.path, start=offset, end=offset + length)  # type: ignore[attr-defined]


def where(location: Any) -> str:
    """A location as a short, printable text for a message (a UPath without its options;
    an escape sequence in a URL never reaches the terminal)."""
    return printable(str(location))


@contextmanager
def reaching(location: Any) -> Iterator[None]:
    """Turn the object-store client's failures inside into one StorageError naming ``location``."""
    try:
        yield
    except Exception as exc:
        if not is_storage_fault(exc):
            raise
        raise StorageError(f"{where(location)}: {describe_storage_fault(exc)}") from None


#: The object :func:`check_writable` writes and removes (a unique name per call).
PROBE_PREFIX = ".dyana-probe-"


def check_writable(remote: Any) -> None:
    """StorageError unless a tiny object can be written under the URL ``remote`` and removed:
    its bucket exists, the credentials work and allow writing. Run before any work, so a
    missing bucket is not found after the first shard is built."""
    fs, root = remote.fs, remote.path.rstrip("/")
    probe = f"{root}/{PROBE_PREFIX}{uuid.uuid4().hex}"
    with reaching(remote):
        try:
            fs.pipe_file(probe, b"")
            fs.rm_file(probe)
        except FileNotFoundError:
            bucket = root.split("/", 1)[0]
            raise StorageError(f"{where(remote)}: the bucket {shorten(bucket)!r} does not exist "
                               "(create it first)") from None
        except PermissionError as exc:
            raise StorageError(f"{where(remote)}: not writable with these credentials ({shorten(exc)})") from None
        except OSError as exc:
            raise StorageError(f"{where(remote)}: cannot write ({type(exc).__name__}: {shorten(exc)})") from None


def listed_sizes(remote: Any) -> dict[str, int]:
    """``{relative path: size}`` of every object under the URL ``remote`` (a UPath), listed
    afresh (not from the filesystem's cache); empty when nothing is there."""
    fs, root = remote.fs, remote.path.rstrip("/")
    fs.invalidate_cache()
    try:
        found = fs.find(root, detail=True)
    except FileNotFoundError:
        return {}
    return {name[len(root) + 1:]: int(info["size"]) for name, info in found.items() if name.startswith(root + "/")}
