"""``catalog.json``: the manifest of a built slice or of a set of evaluated rollouts.

Written last, atomically, as canonical JSON with sorted keys, 2-space indent and a
trailing newline, so its presence marks a complete folder and its bytes depend only
on its content. Its ``hash`` is the slice hash (``catalog.hashing.slice_hash``) over
the settings and the ordered file hashes; loading checks it, so a hand-edited
manifest is refused. Keys beyond the contract's (``policy`` for rollouts, ...) are
kept in :attr:`Manifest.extra` and written at the top level.
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

from catalog.atomic import atomic_write_text
from catalog.hashing import canonical_json, is_sha256, slice_hash
from catalog.records import FileRecord, ShardRecord
from catalog.repeat_sets import repeats_hint
from catalog.storage import as_location
from schemas.errors import ShardError, SpecError
from schemas.formats import stored_formats
from schemas.versions import CODE_VERSION

MANIFEST_NAME = "catalog.json"
CORE_KEYS = ("slice", "seed", "episodes", "frames", "code", "settings", "shards", "hash")
#: Keys of the contract a manifest may lack: ``stats`` (the statistics file's record).
OPTIONAL_KEYS = ("stats",)
_COMMIT = re.compile(r"^[0-9a-f]{40}([0-9a-f]{24})?$")


@dataclass(frozen=True)
class CodeInfo:
    """The code that wrote a folder: package version and git commit (``None`` outside a checkout)."""

    version: str
    commit: str | None

    def __post_init__(self) -> None:
        if not isinstance(self.version, str) or not self.version:
            raise ShardError(f"code.version must be a non-empty string, got {self.version!r}")
        if self.commit is not None and not (isinstance(self.commit, str) and _COMMIT.match(self.commit)):
            raise ShardError(f"code.commit must be a hex git sha or null, got {self.commit!r}")

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

    def __post_init__(self) -> None:
        if not isinstance(self.slice, str) or not self.slice:
            raise ShardError(f"slice must be a non-empty string, got {self.slice!r}")
        if self.seed is not None and (isinstance(self.seed, bool) or not isinstance(self.seed, int)):
            raise ShardError(f"seed must be an integer or null, got {self.seed!r}")
        code = self.code
        if isinstance(code, Mapping) and set(code) == {"version", "commit"}:
            code = CodeInfo(code["version"], code["commit"])
        if not isinstance(code, CodeInfo):
            raise ShardError(f"code must be a CodeInfo or {{version, commit}}, got {self.code!r}")
        object.__setattr__(self, "code", code)
        if not isinstance(self.settings, Mapping):
            raise ShardError(f"settings must be an object, got {self.settings!r}")
        settings = dict(self.settings)
        try:
            canonical_json(settings)
        except (TypeError, ValueError) as exc:
            raise ShardError(f"settings must be plain JSON values: {exc}") from None
        object.__setattr__(self, "settings", MappingProxyType(settings))
        shards = tuple(self.shards)
        for i, shard in enumerate(shards):
            if not isinstance(shard, ShardRecord):
                raise ShardError(f"shards[{i}] must be a ShardRecord, got {shard!r}")
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
        clash = sorted(set(self.extra) & {*CORE_KEYS, *OPTIONAL_KEYS})
        if clash:
            raise ShardError(f"extra keys must not redefine {clash}")
        extra = dict(self.extra)
        try:
            canonical_json(extra)
        except (TypeError, ValueError) as exc:
            raise ShardError(f"extra keys must be plain JSON values: {exc}") from None
        object.__setattr__(self, "extra", MappingProxyType(extra))
        if not is_sha256(self.hash):
            raise ShardError(f"hash must be a sha256 hex digest, got {self.hash!r}")
        if self.stats is not None and not isinstance(self.stats, FileRecord):
            raise ShardError(f"stats must be a file record, got {self.stats!r}")
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
    ) -> Manifest:
        """Totals and hash computed; shards sorted by first episode; ``code`` defaults to this installation."""
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
        )

    def to_dict(self) -> dict[str, Any]:
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
        out.update(self.extra)
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
            raise ShardError(f"code must be an object with version and commit, got {code!r}")
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
            extra={k: v for k, v in data.items() if k not in CORE_KEYS and k not in OPTIONAL_KEYS},
            stats=None if data.get("stats") is None else FileRecord.from_dict(data["stats"], "stats"),
        )

    def files(self) -> list[tuple[str, str, int]]:
        """(path, sha256, size) of every listed file, in hashing order."""
        return [(f.path, f.sha256, f.size) for s in self.shards for f in s.files.values()]


def manifest_path(directory: str | os.PathLike[str]) -> Path:
    return as_location(directory) / MANIFEST_NAME


def write_manifest(directory: str | os.PathLike[str], manifest: Manifest) -> Path:
    """Write ``DIR/catalog.json`` atomically; returns its path."""
    return atomic_write_text(manifest_path(directory), manifest.to_json())


def load_manifest(directory: str | os.PathLike[str]) -> Manifest:
    """Read and validate ``DIR/catalog.json``; ShardError naming the file on any problem."""
    path = manifest_path(directory)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        hint = repeats_hint(directory)  # a folder of repeats says what to pass instead
        raise ShardError(
            hint or f"{path}: no catalog.json (not a built slice or run folder, or the build did not finish)"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ShardError(f"{path}: cannot read: {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ShardError(f"{path}: not valid JSON: {exc}") from None
    try:
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
    directory = Path(repo_dir) if repo_dir is not None else package_file.parent.parent

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
