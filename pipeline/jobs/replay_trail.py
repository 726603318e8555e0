"""Replaying a run whose policy kind keeps an audit trail (the VLM's): the policy runs
again on the re-rendered frames with its answers read from the trail, and the exchanges
it records are compared with the trail's, field by field.

What replay re-derives this way: each exchange's episode, query number, frame, images,
prompt, request settings (model, temperature, seed, ...: from the manifest's
configuration), outcome, detail and parsed answer. What it cannot (the model's replies)
is covered by the trail files' sha256 in the sealed manifest (key ``audit``). Every
listed file must be one shard's (``audit-<first>-<end>.jsonl``) and every record of it
must be asked for by that shard's episodes, in order.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from catalog.store.manifest import MANIFEST_NAME, Manifest
from catalog.store.records import ShardRecord
from pipeline.jobs.audit import audit_path, read_audit, stamped
from pipeline.loop.rollout import RolloutResult, run_episode
from pipeline.loop.wrappers import RecordEpisode
from pipeline.policies.base import Policy
from pipeline.policy_registry import KINDS, Audited, Config, PolicyKind
from schemas.errors import ShardError
from schemas.names import printable
from schemas.spec import EpisodeSpec

Record = dict[str, Any]


@dataclass(frozen=True)
class AuditedReplay:
    """A run of an audited kind: its configuration (from the manifest) and its trail."""

    kind: PolicyKind
    config: Config
    root: Path
    manifest: Manifest

    def policy(self, records: list[Record]) -> Policy:
        """The kind's replaying policy, answering from ``records``."""
        assert self.kind.replay is not None  # only kinds with a replay are chosen
        return self.kind.replay(self.config, records)

    def shard_trail(self, shard: ShardRecord) -> tuple[str, dict[str, list[Record]]]:
        """The path of ``shard``'s trail file and its records by episode id (in order)."""
        assert self.kind.audit_dir is not None
        path = audit_path(self.root / self.kind.audit_dir, shard.first, shard.end).relative_to(self.root).as_posix()
        record = next((r for r in self.manifest.audit or () if r.path == path), None)
        if record is None:
            raise ShardError(f"{self.root}/{MANIFEST_NAME}: lists no audit trail {path} for shard {list(shard.episodes)}")
        by_episode: dict[str, list[Record]] = {}
        for i, entry in enumerate(read_audit(self.root, [record])):
            if not isinstance(entry, dict):
                raise ShardError(f"{self.root / path}: record {i + 1} is not a JSON object")
            by_episode.setdefault(str(entry.get("episode_id")), []).append(entry)
        return path, by_episode

    def recording(self, env: RecordEpisode, spec: EpisodeSpec, records: list[Record]) -> tuple[RolloutResult, list[Record]]:
        """The episode run again from ``records``, and the exchanges it records itself."""
        policy = self.policy(records)
        result = run_episode(env, policy, spec, None)
        return result, stamped(policy.take_audit(), spec.episode_id) if isinstance(policy, Audited) else []


def audited_replay(root: Path, manifest: Manifest) -> AuditedReplay | None:
    """The audited replay of a run whose manifest names an audited kind's configuration
    (its trail listed in the manifest), else None."""
    for kind in KINDS:
        key = kind.manifest_key
        if key is not None and key in manifest.extra and kind.audit_dir is not None and kind.replay is not None:
            config = manifest.extra[key]
            if not isinstance(config, Mapping):
                raise ShardError(f"{root}/{MANIFEST_NAME}: {key} must be an object, got {type(config).__name__}")
            if manifest.audit is None:
                raise ShardError(f"{root}/{MANIFEST_NAME}: a {kind.name} run whose manifest lists no audit trail")
            expected = [audit_path(root / kind.audit_dir, s.first, s.end).relative_to(root).as_posix()
                        for s in manifest.shards]
            listed = [record.path for record in manifest.audit]
            if sorted(listed) != sorted(expected):
                odd = sorted(set(listed) ^ set(expected))
                raise ShardError(f"{root}/{MANIFEST_NAME}: audit lists {len(listed)} trail file(s), one per shard expected "
                                 f"({len(expected)}); differs at {printable(', '.join(odd), 120)}")
            return AuditedReplay(kind, dict(config), root, manifest)
    return None


def _plain(value: Any) -> Any:
    """``value`` as its JSON reads back (what the trail file holds)."""
    return json.loads(json.dumps(value, sort_keys=True, allow_nan=False))


def _first_path(old: Any, new: Any, path: str) -> tuple[str, Any, Any] | None:
    """The dotted path of the first (sorted) key where two JSON values differ, with both values."""
    if isinstance(old, dict) and isinstance(new, dict):
        for key in sorted(set(old) | set(new), key=str):
            found = _first_path(old.get(key, "(absent)"), new.get(key, "(absent)"), f"{path}.{key}")
            if found is not None:
                return found
        return None
    return None if old == new else (path, old, new)


def trail_difference(recorded: list[Record], replayed: list[Record]) -> str | None:
    """The first difference between an episode's recorded and re-derived exchanges:
    ``record N (query Q), field F: recorded X, replay gives Y``, or a count; None if equal."""
    replayed = _plain(replayed)
    for i, (old, new) in enumerate(zip(recorded, replayed)):
        found = _first_path(old, new, "")
        if found is not None:
            field, was, now = found
            return (f"record {i + 1} (query {printable(old.get('query'), 20)}), field {printable(field[1:], 60)}: "
                    f"recorded {printable(json.dumps(was), 120)}, replay gives {printable(json.dumps(now), 120)}")
    if len(recorded) != len(replayed):
        return f"the trail holds {len(recorded)} record(s) of this episode, replay re-derives {len(replayed)}"
    return None
