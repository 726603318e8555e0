"""Sharded jobs whose output folder is an object-store URL (``--out s3://bucket/prefix``):
:func:`pipeline.jobs.runner.run_job` runs a job here when its storage is a URL, holding
:func:`remote_job` (the lock, the writable check) and starting from :func:`prepare_remote`.

The workers write the shards straight to the store, from whichever host they run on
(:class:`pipeline.jobs.sink.ShardSink`: each task writes its shard in a scratch folder of
its own host, then uploads every file as one object); the driver only schedules, collects
the shards' records and writes the job's own files. It keeps those (its lock, the resume
state, the statistics) in a small local folder (``$DYANA_STAGING/<sha256 of the URL>``,
default ``~/.cache/dyana/staging``) and publishes them as it goes:

- a shard counts once its record is in the job's state in the store
  (``.build-state.json``), which the driver uploads after the task returned, i.e. after
  every object of the shard was uploaded whole: an object appears whole or not at all,
  and a shard cut short (its worker killed, its host gone) is listed nowhere, is run again
  on another worker and overwrites what it left with the same bytes;
- at the end every listed object is checked present at its size, ``stats.json`` (merged
  from the partial statistics the tasks returned: no shard is read back) is uploaded,
  then ``catalog.json`` last; then objects of a replaced job and the remote state are
  deleted, and the staging folder and both lock files are removed (while the URL's lock is
  still held, so no other process of this machine has begun on it).

Before starting, the URL is checked writable (a tiny probe object written and removed:
the bucket exists, the credentials and endpoint work), and the client's failures are one
:class:`~schemas.errors.StorageError` naming the URL (:mod:`catalog.store.storage`). Then a
remote ``catalog.json`` describing this job, written by code that may have written these
bytes (the one rule of :func:`pipeline.jobs.state.code_decision`, as for a local folder:
after another commit one sample shard is rebuilt locally and compared first), with every
listed object present at its size means "up to date" (nothing is downloaded); one
describing another job is refused unless ``overwrite``, as locally; otherwise the shards the remote state lists
whose objects are all present at their sizes are kept (nothing is downloaded), so a job
killed on one machine resumes on any other from the store alone.
Two processes of one machine writing one URL are refused (FolderBusy) by a lock beside
the local folder (``<staging>.lock``), held for the whole job; two machines writing
one URL at once are not prevented (object stores have no locks). "Up to date" and resume
check the objects' sizes (an object store gives no sha256 without downloading every byte).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import shutil
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from catalog.store.manifest import MANIFEST_NAME, Manifest, git_commit
from catalog.store.records import ShardRecord
from catalog.store.storage import as_location, check_writable, listed_sizes, reaching
from pipeline.jobs.lock import LOCK_FILE, held
from pipeline.jobs.sink import ShardSink
from pipeline.jobs.state import (
    REBUILD,
    SAMPLE,
    STATE_FILE,
    Identity,
    code_decision,
    describe_difference,
    manifest_identity,
)
from schemas.errors import ShardError, SpecError
from schemas.names import shorten


def staging_folder(url: str) -> Path:
    """The local folder a job for ``url`` runs in."""
    base = os.environ.get("DYANA_STAGING") or Path.home() / ".cache" / "dyana" / "staging"
    return Path(base) / hashlib.sha256(url.encode()).hexdigest()[:24]


def _remote_json(remote: Any, name: str) -> dict | None:
    path = remote / name
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise ShardError(f"{path}: unreadable ({type(exc).__name__}: {str(exc)[:80]})") from None


def _upload(local: Path, remote: Any, rel: str) -> None:
    remote.fs.put_file(os.fspath(local / rel), f"{remote.path.rstrip('/')}/{rel}")


def _empty(staging: Path) -> None:
    """Remove what a staging folder holds, except its lock file."""
    for child in staging.iterdir() if staging.is_dir() else ():
        if child.name != LOCK_FILE:
            shutil.rmtree(child) if child.is_dir() else child.unlink()


def _clear_foreign_staging(staging: Path, wanted: Identity) -> None:
    """Empty the staging folder if it holds another job's state (or unreadable state): it is
    this tool's cache, never a user's folder."""
    try:
        state = json.loads((staging / STATE_FILE).read_text())
        held = state["identity"]
    except FileNotFoundError:
        try:
            held = manifest_identity(Manifest.from_dict(json.loads((staging / MANIFEST_NAME).read_text())))
        except FileNotFoundError:
            return
        except (OSError, ValueError, ShardError):
            held = None
    except (OSError, ValueError, KeyError, TypeError):
        held = None
    if held != wanted:
        _empty(staging)


def _records_of(data: dict | None, key: str) -> list[ShardRecord]:
    try:
        return [ShardRecord.from_dict(raw) for raw in (data or {}).get(key, [])]
    except ShardError as exc:
        raise ShardError(f"remote {key}: {exc}") from None


@contextlib.contextmanager
def remote_job(url: str) -> Iterator[tuple[Path, Any]]:
    """Hold this machine's lock for ``url`` (beside its staging folder) and check the URL
    writable (bucket, credentials, endpoint: before any work); yield the staging folder
    and the store's location. The bucket going away during the job is one ShardError."""
    staging = staging_folder(url)
    staging.parent.mkdir(parents=True, exist_ok=True)
    outer = staging.with_name(staging.name + ".lock")
    try:
        with held(outer, url), reaching(url):
            remote = as_location(url)
            check_writable(remote)
            yield staging, remote
            # finished (or up to date): nothing of this job stays on this machine. Both lock
            # files go while the outer one is held, so no other process of this machine has
            # begun on the URL (it would have been refused as busy).
            shutil.rmtree(staging, ignore_errors=True)
            outer.unlink(missing_ok=True)
    except FileNotFoundError as exc:  # s3fs: the bucket went away during the job
        raise ShardError(f"{shorten(url)}: {exc}") from None


def prepare_remote(url: str, staging: Path, remote: Any, wanted: Identity, overwrite: bool,
                   sample: Callable[[Manifest, str | None], None]) -> Manifest | None:
    """Read what ``url`` holds: its manifest when it holds this job complete ("up to date":
    nothing to run; written by another commit, ``sample(manifest, this_commit)`` rebuilds one
    of its shards first and refuses a difference), else None once the staging folder holds
    the remote state of this job's interrupted run (if any) to resume from; another job's
    folder or state is refused unless ``overwrite``."""
    manifest_data = _remote_json(remote, MANIFEST_NAME)
    sizes = listed_sizes(remote)
    held = None
    if manifest_data is not None:
        try:
            held = Manifest.from_dict(manifest_data)
        except ShardError as exc:
            if not overwrite:
                raise ShardError(f"{url}/{MANIFEST_NAME}: {exc} (pass --overwrite to replace it)") from None
    if held is not None:
        identity = manifest_identity(held)
        if identity != wanted and not overwrite:
            raise SpecError(f"{url} holds another job ({describe_difference(identity, wanted)}): "
                            "choose another --out, or pass --overwrite to replace it")
        listed = [(path, size) for path, _, size in held.files()]
        commit = git_commit()
        decision = code_decision(held.code.version, held.code.commit, held.versions, commit)
        if identity == wanted and decision != REBUILD and not (decision == SAMPLE and overwrite) and all(
            sizes.get(path) == size for path, size in listed
        ):
            if decision == SAMPLE:
                sample(held, commit)
            return held
    state = _remote_json(remote, STATE_FILE)
    if state is not None and state.get("identity") not in (None, wanted) and not overwrite:
        raise SpecError(f"{url} holds an unfinished run of another job "
                        f"({describe_difference(state['identity'], wanted)}): pass --overwrite to replace it")
    _clear_foreign_staging(staging, wanted)
    staging.mkdir(parents=True, exist_ok=True)
    if state is not None and state.get("identity") == wanted:
        _records_of(state, "shards")  # unreadable records: one error naming the remote state
        (staging / STATE_FILE).write_text(json.dumps(state, sort_keys=True, indent=2) + "\n")
    return None


@dataclasses.dataclass(frozen=True)
class ObjectStore:
    """The engine's destination for a URL: the tasks write their shards to ``url`` from their
    own hosts (:attr:`sink`); the driver keeps the job's own files in ``folder`` (the
    staging folder) and uploads the state after each finished shard; at the end the files
    ``folder`` holds (the statistics), then ``catalog.json`` last; then objects of a
    replaced job and the remote state are deleted and the staging folder is emptied."""

    folder: Path
    remote: Any
    url: str

    @property
    def sink(self) -> ShardSink:
        return ShardSink(self.url)

    def unit_done(self, paths: Sequence[str]) -> None:
        """The shard's objects are in the store (its task uploaded them): publish the state."""
        _upload(self.folder, self.remote, paths[-1])

    def job_done(self, paths: Sequence[str]) -> None:
        *files, last = paths
        for path in files:
            if (self.folder / path).is_file():  # the job's own files; the shards are in the store
                _upload(self.folder, self.remote, path)
        _upload(self.folder, self.remote, last)
        keep = set(paths)
        for path in listed_sizes(self.remote):
            if path == STATE_FILE or (path not in keep and path.split("/")[0] in ("frames", "episodes", "mcap")):
                self.remote.fs.rm_file(f"{self.remote.path.rstrip('/')}/{path}")
        _empty(self.folder)
