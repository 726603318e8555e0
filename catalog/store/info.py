"""What a folder is, from its ``catalog.json`` alone (``catalog info DIR|URL``): which code
and dataset version wrote it, what it holds, and whether this installation can rebuild it
byte for byte. Nothing is hashed or decoded; ``catalog verify`` checks the files."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from catalog.store.manifest import MANIFEST_NAME, Manifest, load_manifest
from catalog.store.storage import as_location, is_remote
from catalog.store.versions import installed_versions, version_differences
from schemas.errors import ShardError, SpecError
from schemas.renderers import REBUILDABLE_DATASET_VERSIONS, renderer_of
from schemas.runs import is_run
from schemas.settings import BuildSettings, setting_names
from schemas.versions import HAND_MODEL, POSE_HAND_COMMIT, READABLE_DATASET_VERSIONS

#: The folder kinds: a built slice (ground truth) or a policy's evaluated rollouts.
KINDS = ("slice", "rollouts")


@dataclass(frozen=True)
class Rebuild:
    """Whether this installation re-executes the folder byte for byte, and why (not)."""

    possible: bool
    reason: str

    def to_dict(self) -> dict[str, object]:
        return {"possible": self.possible, "reason": self.reason}


def hand_mismatch(manifest: Manifest) -> str | None:
    """Why a run recorded with another hand model (:data:`schemas.versions.HAND_MODEL`)
    cannot be re-executed byte for byte here (None when it can, or is not a run): its
    rollouts depend on the hand."""
    hand = manifest.settings.get("hand_model")
    if not is_run(manifest.extra) or hand == HAND_MODEL:
        return None
    recorded = "before the hand was a body (no settings.hand_model)" if hand is None else f"with hand {hand!r}"
    return (f"a run recorded {recorded}; this code's closed loop has hand {HAND_MODEL!r}: readable and scored "
            f"as it is; commit {POSE_HAND_COMMIT} re-executes it")


def rebuild_verdict(manifest: Manifest, installed: Mapping[str, str | None] | None = None) -> Rebuild:
    """Only the dataset versions this code writes are rebuilt byte for byte (5.0.0 with the
    ``window`` renderer: :mod:`schemas.renderers`; an older one is
    read, scored and exported); a real-time run depends on the machine's timing; and the
    bytes are the same only with the library versions the folder records
    (:func:`catalog.store.versions.version_differences` against ``installed``, default this
    installation's)."""
    version = manifest.settings.get("dataset_version")
    renderer = renderer_of(version)
    if renderer is None:
        readable = "readable, not re-executable" if version in READABLE_DATASET_VERSIONS else (
            f"not readable either (this code reads dataset {', '.join(READABLE_DATASET_VERSIONS)})")
        commit = manifest.code.commit
        where = f"; check out commit {commit} to rebuild it" if commit else ""
        writes = " and ".join(REBUILDABLE_DATASET_VERSIONS)
        return Rebuild(False, f"written by dataset {version}; this code writes {writes}: {readable}{where}")
    other_hand = hand_mismatch(manifest)
    if other_hand is not None:
        return Rebuild(False, other_hand)
    protocol = manifest.settings.get("protocol")
    if isinstance(protocol, Mapping) and protocol.get("realtime"):
        return Rebuild(False, "a real-time run (settings.protocol.realtime) depends on the machine's timing")
    same = f"this code writes dataset {version} (--renderer {renderer}), as the folder records"
    if manifest.versions is None:
        return Rebuild(True, f"{same} (it records no library versions: written before Dyana recorded them)")
    here = installed_versions() if installed is None else installed
    libraries = {name: v for name, v in manifest.versions.items() if name != "python"}
    differ = version_differences(libraries, here)
    if differ:
        pins = " ".join(f"'{name}=={v}'" for name, v in sorted(libraries.items()) if v is not None and here.get(name) != v)
        fix = f"pip install {pins}" if pins else "uninstall the libraries it did not use"
        return Rebuild(False, f"{same}, but with other libraries ({'; '.join(differ)}): the rebuilt bytes may "
                              f"differ; to rebuild it byte for byte, {fix}")
    python = version_differences({"python": manifest.versions["python"]}, here) if "python" in manifest.versions else []
    if python:  # the lock pins libraries, not the interpreter: a checked difference, not a verdict
        return Rebuild(True, f"{same}, with the library versions it records ({python[0]}: the bytes depend on the "
                             "libraries, which match; `catalog verify DIR --sample 1` rebuilds a shard to confirm)")
    return Rebuild(True, f"{same}, with the library versions it records")


def shown_settings(settings: Mapping[str, object]) -> dict[str, object]:
    """Every byte setting (:class:`schemas.settings.BuildSettings`) with the value the folder's
    bytes have: the stored ones, and for those a manifest leaves out their defaults
    (``obstacle_clearance`` false, ``protocol`` none: the plain loop; ``hand_model`` none: a
    build, or a run from before the hand body). Settings this code
    cannot read as its own (an older dataset version's) are shown as stored."""
    try:
        typed = BuildSettings.from_dict(settings)
    except SpecError:
        return dict(settings)
    return {name: None if getattr(typed, name) == "" else getattr(typed, name) for name in setting_names()}


@dataclass(frozen=True)
class FolderInfo:
    """A folder's identity and contents, as its manifest records them."""

    path: str
    kind: str  # one of KINDS
    policy: str | None  # rollouts only
    slice: str
    seed: int | None
    dataset_version: str | None
    code_version: str
    commit: str | None
    settings: Mapping[str, object]
    episodes: int
    frames: int
    shards: int
    files: int  # catalog.json, the shards' files and stats.json
    size: int  # their bytes, as catalog.json records them (catalog.json's own as read)
    hash: str
    rebuild: Rebuild
    versions: Mapping[str, str | None] | None  # Python's and the byte-determining libraries' (None: not recorded)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ShardError(f"kind must be one of {list(KINDS)}, got {self.kind!r}")

    def to_dict(self) -> dict[str, object]:
        """The ``catalog info --json`` object."""
        return {
            "path": self.path,
            "kind": self.kind,
            "policy": self.policy,
            "slice": self.slice,
            "seed": self.seed,
            "dataset_version": self.dataset_version,
            "code": {"version": self.code_version, "commit": self.commit},
            "settings": dict(self.settings),
            "episodes": self.episodes,
            "frames": self.frames,
            "shards": self.shards,
            "files": self.files,
            "bytes": self.size,
            "hash": self.hash,
            "rebuild": self.rebuild.to_dict(),
            "versions": None if self.versions is None else dict(self.versions),
        }


def folder_info(location: str) -> FolderInfo:
    """:class:`FolderInfo` of a built slice or run folder (a local path or a URL); a
    ShardError naming the folder when it is missing or holds no readable catalog.json."""
    root = as_location(location)
    if not is_remote(root):
        if root.name == MANIFEST_NAME and root.is_file():
            root = root.parent
        if not root.exists():
            raise ShardError(f"{location}: no such folder")
        if not root.is_dir():
            raise ShardError(f"{location}: not a folder (give a built slice or run folder)")
    manifest = load_manifest(root)
    manifest_bytes = len((root / MANIFEST_NAME).read_bytes())
    recorded = [f for shard in manifest.shards for f in shard.files.values()]
    if manifest.stats is not None:
        recorded.append(manifest.stats)
    policy = manifest.extra.get("policy")
    version = manifest.settings.get("dataset_version")
    return FolderInfo(
        path=str(location),
        kind="rollouts" if is_run(manifest.extra) else "slice",
        policy=None if policy is None else str(policy),
        slice=manifest.slice,
        seed=manifest.seed,
        dataset_version=None if version is None else str(version),
        code_version=manifest.code.version,
        commit=manifest.code.commit,
        settings=dict(manifest.settings),
        episodes=manifest.episodes,
        frames=manifest.frames,
        shards=len(manifest.shards),
        files=1 + len(recorded),
        size=manifest_bytes + sum(f.size for f in recorded),
        hash=manifest.hash,
        rebuild=rebuild_verdict(manifest),
        versions=manifest.versions,
    )
