"""``catalog.json``: the manifest of a built slice or of a set of evaluated rollouts.

Written last, atomically, as canonical JSON with sorted keys, 2-space indent and a
trailing newline, so its presence marks a complete folder and its bytes depend only
on its content. Its ``hash`` is the slice hash (``catalog.store.hashing.slice_hash``) over
the settings and the ordered file hashes: the content's identity. ``key_sha256`` seals
the rest: the sha256 of the canonical JSON of every other top-level key, so an edit of
any key (``policy``, ``privileged``, ``code``, a VLM setting, an added key) is refused
on load naming the key. Keys beyond the contract's (``policy`` for rollouts, ...) are
kept in :attr:`Manifest.extra` and written at the top level; ``audit`` lists files kept
beside the shards that no reader reads but replay checks (a VLM run's exchanges);
``versions`` records Python's and the byte-determining libraries' versions
(:mod:`catalog.store.versions`; absent from folders written before Dyana recorded them).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from catalog.store.atomic import atomic_write_text
from catalog.store.hashing import canonical_json, is_sha256, sha256_bytes, slice_hash
from catalog.store.records import FileRecord, ShardRecord
from catalog.store.repeat_sets import repeats_hint
from catalog.store.storage import as_location, is_remote
from catalog.store.versions import VERSIONS_KEY, checked_versions
from schemas.errors import ShardError, SpecError
from schemas.formats import stored_formats
from schemas.names import printable, shorten
from schemas.regular_files import file_kind, open_regular
from schemas.versions import CODE_VERSION

MANIFEST_NAME = "catalog.json"
CORE_KEYS = ("slice", "seed", "episodes", "frames", "code", "settings", "shards", "hash")
#: Keys of the contract a manifest may lack: ``stats`` (the statistics file's record),
#: ``audit`` (a policy's audit trail files) and ``versions`` (the libraries that wrote it).
OPTIONAL_KEYS = ("stats", "audit", VERSIONS_KEY)
#: The seal: every other top-level key's sha256 (:func:`seal_of`), checked on load.
SEAL_KEY = "key_sha256"
_COMMIT = re.compile(r"^[0-9a-f]{40}([0-9a-f]{24})?$")


@dataclass(frozen=True)
class CodeInfo:
    """The code that wrote a folder: package version and git commit (``None`` outside a checkout)."""

    version: str
    commit: str | None

    def __post_init__(self) -> None:
        if not isinstance(self.version, str) or not self.version:
            raise ShardError(f"code.version must be a non-empty string, got {shorten(repr(self.version))}")
        if self.commit is not None and not (isinstance(self.commit, str) and _COMMIT.match(self.commit)):
            raise ShardError(f"code.commit must be a hex git sha or null, got {shorten(repr(self.commit))}")

    @classmethod
    def current(cls) -> CodeInfo:
        """This installation's version and commit."""
        return cls(CODE_VERSION, git_commit())

    def to_dict(self) -> dict[str, Any]:
        return {"version": self.version, "commit": self.commit}


def compute_hash(
    settings: Mapping[str, Any],
    shards: Sequence[ShardRecord],
    slice_name: str | None = None,
    seed: int | None = None,
    stats: FileRecord | None = None,
) -> str:
    """The slice hash of ``settings``, the shards' file hashes (in the given shard order),
    the slice name, the seed and the statistics file."""
    return slice_hash(
        settings,
        [h for shard in shards for h in shard.file_hashes()],
        slice_name=slice_name,
        seed=seed,
        stats=None if stats is None else stats.sha256,
    )


@dataclass(frozen=True)
class Manifest:
    """The content of ``catalog.json``; build one with :meth:`create`.

    ``code`` may be given as a ``{"version", "commit"}`` dict; it is stored as a
    :class:`CodeInfo`. Construction checks the totals and the hash.
    """

    slice: str
    seed: int | None
    episodes: int
    frames: int
    code: CodeInfo
    settings: Mapping[str, Any]
    shards: tuple[ShardRecord, ...]
    hash: str
    extra: Mapping[str, Any] = field(default_factory=dict)
    stats: FileRecord | None = None
    audit: tuple[FileRecord, ...] | None = None
    versions: Mapping[str, str | None] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.slice, str) or not self.slice:
            raise ShardError(f"slice must be a non-empty string, got {shorten(repr(self.slice))}")
        if self.seed is not None and (isinstance(self.seed, bool) or not isinstance(self.seed, int)):
            raise ShardError(f"seed must be an integer or null, got {shorten(repr(self.seed))}")
        code = self.code
        if isinstance(code, Mapping) and set(code) == {"version", "commit"}:
            code = CodeInfo(code["version"], code["commit"])
        if not isinstance(code, CodeInfo):
            raise ShardError(f"code must be a CodeInfo or {{version, commit}}, got {shorten(repr(self.code))}")
        object.__setattr__(self, "code", code)
        if not isinstance(self.settings, Mapping):
            raise ShardError(f"settings must be an object, got {shorten(repr(self.settings))}")
        settings = dict(self.settings)
        try:
            canonical_json(settings)
        except (TypeError, ValueError) as exc:
            raise ShardError(f"settings must be plain JSON values: {exc}") from None
        object.__setattr__(self, "settings", MappingProxyType(settings))
        shards = tuple(self.shards)
        for i, shard in enumerate(shards):
            if not isinstance(shard, ShardRecord):
                raise ShardError(f"shards[{i}] must be a ShardRecord, got {shorten(repr(shard))}")
            if i and shard.first < shards[i - 1].end:
                raise ShardError(
                    f"shards must be ordered and disjoint: {list(shards[i - 1].episodes)} then {list(shard.episodes)}"
                )
        object.__setattr__(self, "shards", shards)
        try:
            with_mcap = "mcap" in stored_formats(settings)
        except SpecError as exc:
            raise ShardError(str(exc)) from None
        for shard in shards:
            if ("mcap" in shard.files) != with_mcap:
                raise ShardError(
                    f"shard {list(shard.episodes)}: {'no' if with_mcap else 'an'} mcap file, but settings.formats is "
                    f"{settings.get('formats', 'absent (parquet and mcap)')}"
                )
        episodes = sum(s.num_episodes for s in shards)
        frames = sum(s.frames for s in shards)
        if self.episodes != episodes:
            raise ShardError(f"episodes is {self.episodes!r} but the shards hold {episodes}")
        if self.frames != frames:
            raise ShardError(f"frames is {self.frames!r} but the shards hold {frames}")
        clash = sorted(set(self.extra) & {*CORE_KEYS, *OPTIONAL_KEYS, SEAL_KEY})
        if clash:
            raise ShardError(f"extra keys must not redefine {clash}")
        extra = dict(self.extra)
        try:
            canonical_json(extra)
        except (TypeError, ValueError) as exc:
            raise ShardError(f"extra keys must be plain JSON values: {exc}") from None
        object.__setattr__(self, "extra", MappingProxyType(extra))
        if not is_sha256(self.hash):
            raise ShardError(f"hash must be a sha256 hex digest, got {shorten(repr(self.hash))}")
        if self.stats is not None and not isinstance(self.stats, FileRecord):
            raise ShardError(f"stats must be a file record, got {shorten(repr(self.stats))}")
        if self.audit is not None:
            audit = tuple(self.audit)
            if not all(isinstance(r, FileRecord) for r in audit):
                raise ShardError(f"audit must be a list of file records, got {audit!r:.120}")
            paths = [r.path for r in audit]
            if paths != sorted(set(paths)):
                raise ShardError(f"audit must list each file once, sorted by path, got {paths!r:.120}")
            object.__setattr__(self, "audit", audit)
        if self.versions is not None:
            object.__setattr__(self, "versions", checked_versions(self.versions))
        expected = compute_hash(settings, shards, self.slice, self.seed, self.stats)
        if self.hash != expected:
            raise ShardError(
                f"hash {self.hash} does not match the slice, seed, settings, statistics and file hashes ({expected}): "
                "edited, or written before Dyana's manifests covered all of them (rebuild it with --overwrite)"
            )

    @classmethod
    def create(
        cls,
        slice: str,
        seed: int | None,
        settings: Mapping[str, Any],
        shards: Sequence[ShardRecord],
        code: CodeInfo | None = None,
        extra: Mapping[str, Any] | None = None,
        stats: FileRecord | None = None,
        audit: Sequence[FileRecord] | None = None,
        versions: Mapping[str, str | None] | None = None,
    ) -> Manifest:
        """Totals and hash computed; shards sorted by first episode, ``audit`` by path;
        ``code`` defaults to this installation's; ``versions`` is recorded as given (a build
        passes :func:`catalog.store.versions.installed_versions`)."""
        ordered = tuple(sorted(shards, key=lambda s: s.first))
        return cls(
            slice=slice,
            seed=seed,
            episodes=sum(s.num_episodes for s in ordered),
            frames=sum(s.frames for s in ordered),
            code=CodeInfo.current() if code is None else code,
            settings=dict(settings),
            shards=ordered,
            hash=compute_hash(settings, ordered, slice, seed, stats),
            extra=dict(extra or {}),
            stats=stats,
            audit=None if audit is None else tuple(sorted(audit, key=lambda r: r.path)),
            versions=versions,
        )

    def to_dict(self) -> dict[str, Any]:
        """Every key as written, the seal (``key_sha256``) included."""
        out = {
            "slice": self.slice,
            "seed": self.seed,
            "episodes": self.episodes,
            "frames": self.frames,
            "code": self.code.to_dict(),
            "settings": dict(self.settings),
            "shards": [s.to_dict() for s in self.shards],
            "hash": self.hash,
        }
        if self.stats is not None:
            out["stats"] = self.stats.to_dict()
        if self.audit is not None:
            out["audit"] = [r.to_dict() for r in self.audit]
        if self.versions is not None:
            out[VERSIONS_KEY] = dict(self.versions)
        out.update(self.extra)
        out[SEAL_KEY] = seal_of(json.loads(canonical_json(out)))  # over the values as a reader gets them back
        return out

    def to_json(self) -> str:
        """Sorted keys, 2-space indent, ASCII, trailing newline."""
        return json.dumps(self.to_dict(), sort_keys=True, indent=2, ensure_ascii=True, allow_nan=False) + "\n"

    @classmethod
    def from_dict(cls, data: Any) -> Manifest:
        if not isinstance(data, dict):
            raise ShardError(f"manifest must be a JSON object, got {type(data).__name__}")
        missing = [k for k in CORE_KEYS if k not in data]
        if missing:
            raise ShardError(f"manifest is missing key(s) {missing}")
        code = data["code"]
        if not isinstance(code, dict) or "version" not in code or "commit" not in code:
            raise ShardError(f"code must be an object with version and commit, got {shorten(repr(code))}")
        if not isinstance(data["shards"], list):
            raise ShardError(f"shards must be a list, got {data['shards']!r}")
        shards = tuple(ShardRecord.from_dict(s, f"shards[{i}]") for i, s in enumerate(data["shards"]))
        return cls(
            slice=data["slice"],
            seed=data["seed"],
            episodes=data["episodes"],
            frames=data["frames"],
            code=CodeInfo(code["version"], code["commit"]),
            settings=data["settings"],
            shards=shards,
            hash=data["hash"],
            extra={k: v for k, v in data.items() if k not in {*CORE_KEYS, *OPTIONAL_KEYS, SEAL_KEY}},
            stats=None if data.get("stats") is None else FileRecord.from_dict(data["stats"], "stats"),
            audit=_audit_records(data.get("audit")),
            versions=data.get(VERSIONS_KEY),
        )

    def files(self) -> list[tuple[str, str, int]]:
        """(path, sha256, size) of every listed file, in hashing order."""
        return [(f.path, f.sha256, f.size) for s in self.shards for f in s.files.values()]


def _audit_records(raw: Any) -> tuple[FileRecord, ...] | None:
    if raw is None:
        return None
    if not isinstance(raw, list):
        raise ShardError(f"audit must be a list of file records, got {printable(raw)}")
    return tuple(FileRecord.from_dict(r, f"audit[{i}]") for i, r in enumerate(raw))


def seal_of(data: Mapping[str, Any]) -> dict[str, str]:
    """The seal of a manifest's keys: each key but the seal itself mapped to the sha256
    of its value's canonical JSON (``catalog.store.hashing.canonical_json``)."""
    return {k: sha256_bytes(canonical_json(v).encode("utf-8")) for k, v in data.items() if k != SEAL_KEY}


def check_seal(data: Mapping[str, Any], *, required: bool = True) -> bool:
    """ShardError naming the keys edited, added or removed since the manifest was written;
    a manifest without a seal (written before Dyana sealed its manifests) is refused
    unless ``required`` is false. Returns whether it had one."""
    seal = data.get(SEAL_KEY)
    if seal is None:
        if required:
            raise ShardError(
                f"written before Dyana sealed every key of its manifests (no {SEAL_KEY}): run `catalog migrate DIR` "
                "on its folder (it verifies every file, then seals the manifest)"
            )
        return False
    if not isinstance(seal, dict) or not all(isinstance(v, str) for v in seal.values()):
        raise ShardError(f"{SEAL_KEY} must be an object of sha256 digests, got {printable(seal)}")
    now = seal_of(data)
    changed = sorted(k for k in now if k in seal and seal[k] != now[k])
    added = sorted(k for k in now if k not in seal)
    removed = sorted(k for k in seal if k not in now)
    if changed or added or removed:
        parts = [f"{what} {printable(', '.join(keys), 80)}" for what, keys in
                 (("changed:", changed), ("added:", added), ("removed:", removed)) if keys]
        raise ShardError(f"edited after it was written ({'; '.join(parts)}; {SEAL_KEY} differs): "
                         "restore it, or rebuild the folder")
    return True


def manifest_path(directory: str | os.PathLike[str]) -> Path:
    return as_location(directory, "directory") / MANIFEST_NAME


def write_manifest(directory: str | os.PathLike[str], manifest: Manifest) -> Path:
    """Write ``DIR/catalog.json`` atomically; returns its path."""
    return atomic_write_text(manifest_path(directory), manifest.to_json())


def _read_regular(path: Path) -> str:
    """A local file's text, if it is a regular file: a FIFO (or a link to a device such as
    /dev/zero) in catalog.json's place would block every reader or stream for ever."""
    opened, status = open_regular(path)
    if opened is None:
        raise ShardError(f"{path}: not a regular file ({file_kind(status.st_mode)}), so not a manifest")
    with opened as handle:
        return handle.read().decode("utf-8")


class _NotJson(ValueError):
    """``NaN``, ``Infinity`` or ``-Infinity`` in a JSON text: Python reads them, JSON has none."""


def _refuse_constant(name: str) -> float:
    raise _NotJson(name)


def dyana_subfolders(directory: str | os.PathLike[str]) -> list[str]:
    """Names of the local sub-folders that hold a catalog.json (``pipeline build --out OUT``
    writes ``OUT/SLICE``): what a reader given ``OUT`` suggests instead."""
    root = as_location(directory)
    try:
        if is_remote(root) or not root.is_dir():
            return []
        return sorted(p.name for p in root.iterdir() if (p / MANIFEST_NAME).is_file())
    except OSError:
        return []


def _parent_hint(directory: str | os.PathLike[str]) -> str | None:
    """For a folder that holds built folders rather than being one: one line naming them."""
    inside = dyana_subfolders(directory)
    if not inside:
        return None
    shown = ", ".join(inside[:4]) + (", ..." if len(inside) > 4 else "")
    return (f"{directory}: no catalog.json here; it holds Dyana folders ({shown}): "
            f"give one of them, e.g. {as_location(directory) / inside[0]}")


def load_manifest(directory: str | os.PathLike[str], *, sealed: bool = True) -> Manifest:
    """Read and validate ``DIR/catalog.json``, its seal first; ShardError naming the file
    on any problem. ``sealed=False`` accepts a manifest without a seal (``catalog migrate``
    reads the previous release's so; a seal present is still checked)."""
    path = manifest_path(directory)
    try:
        text = path.read_text(encoding="utf-8") if is_remote(path) else _read_regular(path)
    except FileNotFoundError:
        hint = repeats_hint(directory) or _parent_hint(directory)  # what to pass instead
        raise ShardError(
            hint or f"{path}: no catalog.json (not a built slice or run folder, or the build did not finish)"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ShardError(f"{path}: cannot read: {exc}") from None
    try:
        data = json.loads(text, parse_constant=_refuse_constant)
    except json.JSONDecodeError as exc:
        raise ShardError(f"{path}: not valid JSON: {exc}") from None
    except _NotJson as exc:
        raise ShardError(f"{path}: holds {exc}, which JSON does not allow (and Dyana never writes)") from None
    except ValueError as exc:  # an integer of more digits than Python converts (sys.int_info)
        raise ShardError(f"{path}: holds a number Dyana cannot read: {shorten(str(exc), 160)}") from None
    except RecursionError:
        raise ShardError(f"{path}: JSON nested too deeply") from None
    try:
        if not isinstance(data, dict):
            raise ShardError(f"manifest must be a JSON object, got {type(data).__name__}")
        try:
            check_seal(data, required=sealed)
        except ShardError as exc:
            raise ShardError(str(exc).replace("catalog migrate DIR", f"catalog migrate {printable(str(directory))}")) from None
        return Manifest.from_dict(data)
    except ShardError as exc:
        raise ShardError(f"{path}: {exc}") from None


def git_commit(repo_dir: str | os.PathLike[str] | None = None) -> str | None:
    """The commit checked out at ``repo_dir`` (default: the checkout holding this package).

    Returns the bare hex sha of ``HEAD``: no ``-dirty`` suffix, no path. ``None`` when
    git is missing, the directory is not in a checkout, or, by default, when the
    package is not a file tracked by that checkout (an install inside some other repo).
    A dirty working tree is not detected: the commit then names the nearest code.
    """
    package_file = Path(__file__).resolve()
    directory = Path(repo_dir) if repo_dir is not None else package_file.parents[2]

    def git(*args: str) -> str | None:
        env = {k: v for k, v in os.environ.items() if not k.startswith("GIT_")}
        try:
            done = subprocess.run(
                ["git", "-C", str(directory), *args], capture_output=True, text=True, timeout=10, env=env
            )
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    if repo_dir is None:
        relative = (package_file.parent / "__init__.py").relative_to(directory).as_posix()
        if git("ls-files", "--error-unmatch", relative) is None:
            return None
    sha = git("rev-parse", "--verify", "HEAD")
    return sha if sha and _COMMIT.match(sha) else None
