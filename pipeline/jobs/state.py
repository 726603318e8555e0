"""What a job's folder already holds: the job it describes, the shards it may keep.

A folder holds one job, described by its identity (slice, seed, episodes, shard ranges,
settings and the extra manifest keys): a finished job's ``catalog.json``, or the
``.build-state.json`` an interrupted run leaves (identity, code, finished shards and what
the job keeps of their tasks' results: partial statistics, an eval's counts).

Whether the recorded code may have written this code's bytes is one rule,
:func:`code_decision`, for a local folder (:func:`previous_work`) and an object store
(:mod:`pipeline.jobs.object_store`) alike: the package version (written into every MCAP
file) and the byte-determining library versions (:mod:`catalog.store.versions`) must match, or
every shard is rebuilt (no folder mixes shards of two installations). The git commit does
not decide it (a docs-only commit changes no byte), but after another commit (or an
unknown one) one sample shard is rebuilt and compared first (:mod:`pipeline.jobs.resume`).
A shard is kept only when every one of its files still has its size and sha256; a folder
is "up to date" only when every shard, the statistics file and the audit trail files pass
that check.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from catalog.store.atomic import atomic_write_text
from catalog.store.manifest import Manifest, load_manifest, manifest_path
from catalog.store.records import FileRecord, ShardRecord
from catalog.store.versions import installed_versions
from catalog.tables.reader import check_file
from schemas.errors import ShardError, SpecError
from schemas.renderers import renderer_of
from schemas.versions import CODE_VERSION

STATE_FILE = ".build-state.json"

#: A job's identity: JSON values by key (``extra.<key>`` for the extra manifest keys).
Identity = dict[str, object]
Range = tuple[int, int]


def identity_of(slice_name: str, seed: int | None, episodes: int, ranges: Sequence[Range],
                settings: Mapping[str, object], extra: Mapping[str, object]) -> Identity:
    """What a folder must hold for a job of these parts to reuse it."""
    return {
        "slice": slice_name,
        "seed": seed,
        "episodes": episodes,
        "shards": [list(r) for r in ranges],
        "settings": dict(settings),
        **{f"extra.{k}": v for k, v in sorted(extra.items())},
    }


def manifest_identity(manifest: Manifest) -> Identity:
    """The identity of the job that wrote ``manifest``."""
    return identity_of(manifest.slice, manifest.seed, manifest.episodes, [s.episodes for s in manifest.shards],
                       manifest.settings, manifest.extra)


def _short(value: object, limit: int = 80) -> str:
    text = json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _flat_settings(identity: Mapping[str, object]) -> dict[str, object]:
    """``identity`` with its settings as ``settings.<key>`` entries, so a difference names the setting."""
    out = {k: v for k, v in identity.items() if k != "settings"}
    settings = identity.get("settings")
    if isinstance(settings, Mapping):
        out.update({f"settings.{k}": v for k, v in settings.items()})
    elif "settings" in identity:
        out["settings"] = settings
    return out


def describe_difference(held: Mapping[str, object], wanted: Mapping[str, object]) -> str:
    """The first few keys on which two identities differ, as ``key held -> wanted`` (a
    dataset version also names the renderer that writes it)."""
    held, wanted = _flat_settings(held), _flat_settings(wanted)
    keys = [k for k in sorted(set(held) | set(wanted)) if held.get(k) != wanted.get(k)]
    if "settings.dataset_version" in keys:
        keys.remove("settings.dataset_version")
        keys.insert(0, "settings.dataset_version")
    if "shards" in keys and "episodes" in keys:
        keys.remove("shards")
    parts = [f"{k} {_short(held.get(k))} -> {_short(wanted.get(k))}" for k in keys[:3]]
    if keys and keys[0] == "settings.dataset_version":
        named = [f"{v} is --renderer {renderer_of(v)}" for v in (held.get(keys[0]), wanted.get(keys[0])) if renderer_of(v)]
        parts[0] += f" ({', '.join(named)})" if named else ""
    if len(keys) > 3:
        parts.append(f"and {len(keys) - 3} more")
    return "; ".join(parts)


def file_intact(folder: Path, record: FileRecord) -> bool:
    """The file is there with its recorded size and sha256."""
    try:
        check_file(folder, record, "sha256")
    except ShardError:
        return False
    return True


def shard_intact(folder: Path, record: ShardRecord) -> bool:
    return all(file_intact(folder, f) for f in record.files.values())


#: :func:`code_decision`'s answers: start over, keep what passes the file checks, or keep it
#: once one sample shard rebuilt by this code has the recorded bytes.
REBUILD, TRUST, SAMPLE = "rebuild", "trust", "sample"


def code_decision(version: object, recorded_commit: object, versions: object, commit: str | None) -> str:
    """Whether shards written by code ``version`` at ``recorded_commit`` under library
    ``versions`` may be kept by this code at ``commit`` (module docstring): :data:`REBUILD`
    when the package or a byte-determining library version differs (the dataset version is
    part of the identity, compared before), :data:`SAMPLE` when the commit differs or either
    is unknown (None: an install without a checkout), else :data:`TRUST`."""
    if version != CODE_VERSION or versions != installed_versions():
        return REBUILD
    if commit is None or recorded_commit != commit:
        return SAMPLE
    return TRUST


@dataclass(frozen=True)
class PreviousWork:
    """Finished shards a job may keep (by range), whether the folder is complete, the
    commit that wrote them and whether one of them must be rebuilt and compared before
    they are trusted (``sample``: :data:`SAMPLE`), and what the resume state kept of their
    tasks' results (by range: partial statistics, an eval's counts)."""

    done: Mapping[Range, ShardRecord] = field(default_factory=dict)
    complete: bool = False
    recorded_commit: str | None = None
    sample: bool = False
    kept: Mapping[Range, dict] = field(default_factory=dict)


def previous_work(folder: Path, wanted: Identity, with_stats: bool, commit: str | None, overwrite: bool,
                  intact: Callable[[ShardRecord], bool] | None = None) -> PreviousWork:
    """What ``folder`` holds of the job ``wanted`` (see the module docstring); ``intact``
    says whether a finished shard's files are still there (default: their sizes and sha256
    in ``folder``; an object store's job checks its objects instead).

    Refuses (SpecError) a folder holding another job unless ``overwrite``, which then
    forgets it (its files are removed once the new job is finished); ``overwrite`` also
    rebuilds, rather than samples, shards of another commit."""
    state_path = folder / STATE_FILE
    held: Identity | None = None
    records: list[ShardRecord] = []
    code: tuple[object, object, object] = (None, None, None)
    complete = False
    results: dict[Range, dict] = {}
    if manifest_path(folder).exists():
        try:
            manifest = load_manifest(folder)
        except ShardError:
            if not overwrite:
                raise
        else:
            held, records = manifest_identity(manifest), list(manifest.shards)
            complete = file_intact(folder, manifest.stats) if manifest.stats is not None else not with_stats
            complete = complete and all(file_intact(folder, record) for record in manifest.audit or ())
            code = (manifest.code.version, manifest.code.commit,
                    None if manifest.versions is None else dict(manifest.versions))
    if held is None and state_path.exists():
        try:
            state = json.loads(state_path.read_text())
            held = state["identity"]
            records = [ShardRecord.from_dict(raw) for raw in state["shards"]]
            code = (state["code"]["version"], state["code"]["commit"], state["code"].get("versions"))
            results = {(r.first, r.end): k for r, k in zip(records, state.get("kept", []), strict=False)
                       if isinstance(k, dict)}
        except (OSError, ValueError, KeyError, TypeError, ShardError) as exc:
            if not overwrite:
                raise ShardError(
                    f"{state_path}: unreadable state of an interrupted run ({type(exc).__name__}); "
                    "pass --overwrite to start the folder afresh"
                ) from None
            held = None
    if held is None:
        return PreviousWork()
    if held != wanted:
        if overwrite:
            manifest_path(folder).unlink(missing_ok=True)
            state_path.unlink(missing_ok=True)
            return PreviousWork()
        what = "holds" if complete else "holds an unfinished run of"
        raise SpecError(
            f"{folder} {what} another job ({describe_difference(held, wanted)}): "
            "choose another --out, or pass --overwrite to replace it"
        )
    decision = code_decision(*code, commit)
    if decision == REBUILD or (decision == SAMPLE and overwrite):
        return PreviousWork()
    kept = (lambda record: shard_intact(folder, record)) if intact is None else intact
    done = {(r.first, r.end): r for r in records if kept(r)}
    recorded = code[1] if isinstance(code[1], str) else None
    return PreviousWork(done, complete and len(done) == len(records), recorded, decision == SAMPLE,
                        {key: results[key] for key in done if key in results})


def save_state(folder: Path, identity: Identity, commit: str | None, done: Mapping[Range, ShardRecord],
               kept: Mapping[Range, dict] | None = None) -> None:
    """Record the finished shards of a running job (what an interrupted run resumes from),
    with what the job keeps of each one's task result (``{}`` where none), in shard order."""
    keys = sorted(done)
    state = {
        "identity": identity,
        "code": {"version": CODE_VERSION, "commit": commit, "versions": installed_versions()},
        "shards": [done[key].to_dict() for key in keys],
        "kept": [(kept or {}).get(key, {}) for key in keys],
    }
    atomic_write_text(folder / STATE_FILE, json.dumps(state, sort_keys=True, indent=2) + "\n")
