"""`pipeline replay`: re-execute a recording and check it comes out byte for byte.

- A built slice: each episode's stored spec goes through the episode stage, the
  renderer and the JPEG encoder again.
- Rollouts (``catalog.json`` has a ``policy``): the environment is reset with the
  stored spec and stepped with the recorded actions (the action column of every
  acting frame but the last). No policy is needed: what the policy saw is the
  decoded JPEG of the recorded image bytes, which replay re-renders and compares.
  A policy kind that keeps an audit trail (:mod:`pipeline.policy_registry`: the VLM's)
  is run again instead, its answers read from the trail, after checking its hashes,
  and every exchange it re-derives is compared with the trail's
  (:mod:`pipeline.jobs.replay_trail`).

Nothing recorded is taken on trust where it can be re-derived: a run's ``status`` comes
from the re-execution (``ok`` when the last recorded step ends the episode, ``error``
when the recording stops before), ``policy`` and ``privileged`` from the manifest,
checked against the policy where replay can make it. Unlisted files in the data
folders are refused first (:func:`catalog.tables.integrity.stray_files`).

Every column of every frame (state arrays bit for bit, the JPEG bytes) and of the
episodes table is compared, then the shard is rewritten into a scratch folder and
its three files' sha256 are compared with the manifest (which also covers the MCAP
and the Parquet metadata). The first difference raises :class:`ReplayMismatch`
naming the shard, episode, frame and column, with both values; :func:`replay` (and
``catalog verify``) add each library version the folder records that differs from the
installed one (:mod:`catalog.store.versions`), the likeliest cause of such a difference.

:func:`replay_shard` is the one place a recorded shard is re-executed: ``catalog verify``
(:mod:`pipeline.jobs.verify`) rebuilds its sampled shards through it too.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from catalog.store.info import hand_mismatch
from catalog.store.manifest import MANIFEST_NAME, Manifest
from catalog.store.records import ShardRecord, shard_stem
from catalog.store.versions import mismatch_note
from catalog.tables.integrity import raise_first, stray_files
from catalog.tables.parquet_io import episode_row, episodes_table, frames_table
from catalog.tables.reader import ShardReader, check_file, open_folder
from generators.heldout import MANIFEST_KEY as HELD_OUT_KEY
from generators.heldout import TestSeed, matching, private_specs
from pipeline.jobs.progress import EpisodeReport, report_quietly
from pipeline.jobs.replay_trail import AuditedReplay, audited_replay, trail_difference
from pipeline.loop.conditions import EvalProtocol
from pipeline.loop.disturb import disturbed_spec
from pipeline.loop.wrappers import RecordEpisode, loop_env
from pipeline.policies.base import BUILTIN, make_policy
from schemas.errors import PolicyError, ReplayMismatch, ShardError, SpecError
from schemas.frames import EpisodeFrames
from schemas.names import printable, shorten
from schemas.renderers import REBUILDABLE_DATASET_VERSIONS, renderer_of
from schemas.settings import BuildSettings
from schemas.spec import EpisodeSpec


@dataclass(frozen=True)
class ReplayReport:
    """What was re-executed: ``kind`` is ``slice`` (ground truth) or ``rollouts``."""

    path: str
    slice: str
    kind: str
    shards: int
    episodes: int
    frames: int


def check_rebuildable(directory: object, manifest: Manifest) -> str:
    """The renderer that re-executes ``manifest``'s dataset version (:mod:`schemas.renderers`),
    or ShardError when this code writes another, or when the folder is a run recorded with
    another hand model (:data:`schemas.versions.HAND_MODEL`): rebuilds and replays compare
    bytes, so such a folder can be read and scored but not re-executed."""
    built_with = manifest.settings.get("dataset_version")
    renderer = renderer_of(built_with)
    if renderer is None:
        raise ShardError(
            f"{directory}/catalog.json: written as dataset version {built_with!r}; this code writes "
            f"{' and '.join(map(repr, REBUILDABLE_DATASET_VERSIONS))}, so its shards cannot be re-executed "
            f"byte for byte (check out the commit {manifest.code.commit or 'that wrote it'})"
        )
    other_hand = hand_mismatch(manifest)
    if other_hand is not None:
        raise ShardError(f"{directory}/catalog.json: {other_hand}")
    return renderer


def recorded_settings(root: object, settings: Mapping[str, Any]) -> BuildSettings:
    """A manifest's settings as :class:`~schemas.settings.BuildSettings`; ShardError naming
    the folder when this code cannot re-execute them (another dataset version, an unknown
    key, a bad value)."""
    if renderer_of(settings.get("dataset_version")) is None:
        raise ShardError(f"{root}: dataset version {settings.get('dataset_version')!r} cannot be re-executed here")
    try:
        return BuildSettings.from_dict(settings)
    except SpecError as exc:
        raise ShardError(f"{root}/{MANIFEST_NAME}: {exc}") from None


#: Where a :class:`ReplayMismatch` happened: its attributes.
MISMATCH_WHERE = ("shard", "episode", "frame", "column", "file")


def _mismatch(message: str, **where: Any) -> ReplayMismatch:
    """A ReplayMismatch carrying ``shard``, ``episode``, ``frame``, ``column`` attributes and
    ``file``, the folder-relative path of the file that differs."""
    exc = ReplayMismatch(message)
    for key in MISMATCH_WHERE:
        setattr(exc, key, where.get(key))
    return exc


def _bits(values: np.ndarray) -> np.ndarray:
    """Values as unsigned integers of the same width, so -0.0 != 0.0 and NaNs compare by payload."""
    values = np.ascontiguousarray(values)
    if values.dtype.kind == "f":
        return values.view(np.dtype(f"u{values.dtype.itemsize}"))
    return values


def _column_values(column: pa.ChunkedArray | pa.Array) -> Any:
    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    if pa.types.is_fixed_size_list(column.type):
        width = column.type.list_size
        return column.flatten().to_numpy(zero_copy_only=False).reshape(-1, width)
    if pa.types.is_integer(column.type) or pa.types.is_floating(column.type) or pa.types.is_boolean(column.type):
        return column.to_numpy(zero_copy_only=False)
    return column.to_pylist()


def _first_row_difference(recorded: Any, expected: Any) -> tuple[int, str] | None:
    """The first row whose values differ, with a description of both values."""
    n = min(len(recorded), len(expected))
    if isinstance(recorded, np.ndarray):
        a, b = _bits(recorded[:n]), _bits(expected[:n])
        differ = a != b
        if differ.ndim > 1:
            rows = np.flatnonzero(differ.any(axis=1))
            if rows.size == 0:
                return None
            row = int(rows[0])
            col = int(np.flatnonzero(differ[row])[0])
            return row, f"[{col}]: recorded {recorded[row, col]}, replay gives {expected[row, col]}"
        rows = np.flatnonzero(differ)
        if rows.size == 0:
            return None
        row = int(rows[0])
        return row, f": recorded {recorded[row]}, replay gives {expected[row]}"
    for row in range(n):
        x, y = recorded[row], expected[row]
        if x != y:
            if isinstance(x, bytes) and isinstance(y, bytes):
                size = min(len(x), len(y))
                at = next((i for i in range(size) if x[i] != y[i]), size)
                return row, f": recorded {len(x)} bytes, replay gives {len(y)} bytes, first difference at byte {at}"
            return row, f": recorded {x!r:.120}, replay gives {y!r:.120}"
    return None


def _first_difference(recorded: pa.Table, expected: pa.Table, columns: Sequence[str]) -> tuple[int, str, str] | None:
    """(row, column, detail) of the earliest difference; among columns of that row, the first in order."""
    best: tuple[int, int, str, str] | None = None
    for order, name in enumerate(columns):
        found = _first_row_difference(_column_values(recorded.column(name)), _column_values(expected.column(name)))
        if found is not None and (best is None or found[0] < best[0]):
            best = (found[0], order, name, found[1])
    if best is None:
        return None
    return best[0], best[2], best[3]


def _rollout_recording(
    env: RecordEpisode, spec: EpisodeSpec, actions: np.ndarray, where: dict
) -> tuple[EpisodeFrames, list[bytes], str]:
    """Reset with the spec and step with the recorded actions of frames observe_frames .. n-2;
    the frames, the images and the status the re-execution gives: ``ok`` when the last
    recorded step ends the episode (grasp complete or horizon), ``error`` when the recording
    stops before (only a failing policy ends an episode early)."""
    env.reset(options={"spec": spec})
    n = len(actions)
    ended = None
    for frame in range(spec.observe_frames, n - 1):
        try:
            _obs, _reward, terminated, truncated, _info = env.step(actions[frame])
        except PolicyError as exc:
            raise _mismatch(
                f"{where['prefix']}, frame {frame}: the recorded action is refused by the environment: {exc}",
                frame=frame, column="action", **where["ids"],
            ) from None
        if terminated or truncated:
            ended = frame + 1
            break
    if ended is not None and ended < n - 1:
        raise _mismatch(
            f"{where['prefix']}: replay ends at frame {ended} (grasp complete or horizon), the recording goes on to frame {n - 1}",
            frame=ended + 1, column="frame_index", **where["ids"],
        )
    frames, images = env.recording()
    return frames, list(images), "ok" if ended is not None else "error"


def _replayed_error(status: str, recorded: str | None, last_frame: int) -> str:
    """The error column replay expects: empty for ``ok``; for ``error`` the recorded text
    when it names the frame the recording stops at (the policy's message itself is not
    re-derivable without the policy), else that frame alone."""
    if status == "ok":
        return ""
    prefix = f"frame {last_frame}: "
    return recorded if isinstance(recorded, str) and recorded.startswith(prefix) else prefix + "(the policy's error)"


def rollout_columns(root: Path, manifest: Manifest, audited: AuditedReplay | None) -> dict[str, Any]:
    """The ``policy`` and ``privileged`` columns every episode of a run must hold, from the
    manifest, after checking them against the policy where replay can make it (a built-in
    name, an audited kind's configuration): ShardError naming catalog.json otherwise."""
    policy, privileged = manifest.extra.get("policy"), manifest.extra.get("privileged")
    where = f"{root}/{MANIFEST_NAME}"
    if not isinstance(policy, str) or not isinstance(privileged, bool):
        raise ShardError(f"{where}: policy must be a name and privileged true or false, got "
                         f"{printable(policy, 60)} and {printable(privileged, 20)}")
    made = audited.policy([]) if audited is not None else (make_policy(policy) if policy in BUILTIN else None)
    if made is not None:
        name, flag = getattr(made, "name", None), bool(getattr(made, "privileged", False))
        if name != policy or flag != privileged:
            raise ShardError(f"{where}: says policy {printable(policy, 60)} (privileged {privileged}), but its "
                             f"configuration makes {printable(name, 60)} (privileged {flag})")
    return {"policy": policy, "privileged": privileged}


def replay_shard(
    reader: ShardReader,
    settings: Mapping[str, Any],
    env: RecordEpisode | None,
    audited: AuditedReplay | None = None,
    report: EpisodeReport | None = None,
    columns: Mapping[str, Any] | None = None,
    drawn: Sequence[EpisodeSpec] | None = None,
) -> int:
    """Re-execute one shard (``env``: the environment for rollouts, None for ground truth),
    compare every column and the rewritten files' sha256, and return its frame count;
    ``report`` hears each episode re-executed; ``columns``: a run's ``policy`` and
    ``privileged`` columns (:func:`rollout_columns`); ``drawn``: the specs its episodes must
    hold (a privately drawn run's, :func:`drawn_specs`). The first difference is a ReplayMismatch."""
    from catalog.tables.shard import ShardWriter

    root, shard, rollout = reader.root, reader.record, reader.rollout
    stem = shard_stem(shard.first, shard.end)
    reader.check_files()
    episodes = reader.episodes()
    frames = reader.frames(None, episodes)
    frame_episode = frames.column("episode_index").to_numpy()
    typed = recorded_settings(root, settings)
    replayed: list[tuple[EpisodeSpec, EpisodeFrames, list[bytes], dict]] = []
    if rollout and columns is None:
        raise ShardError(f"{root}: replaying a run needs its policy columns (rollout_columns)")
    trail_path, trail = audited.shard_trail(shard) if rollout and audited is not None else ("", {})
    for row in episodes.to_pylist():
        index = row["episode_index"]
        spec = EpisodeSpec.from_json(row["spec"])
        ids = {"shard": stem, "episode": index, "file": shard.files["frames"].path}
        prefix = f"{root}: shard {stem}, episode {index} ({spec.episode_id})"
        if drawn is not None and spec.to_json() != drawn[index - shard.first].to_json():
            raise _mismatch(f"{prefix}: the stored spec is not the one the test seed draws", column="spec",
                            shard=stem, episode=index, file=shard.files["episodes"].path)
        recorded = frames.filter(pa.array(frame_episode == index))
        extra: dict[str, Any] = {}
        if rollout and audited is not None and env is not None:
            records = trail.pop(spec.episode_id, [])
            result, asked = audited.recording(env, spec, records)
            ep_frames, images = result.frames, list(result.images)
            extra = {"status": result.status, "error": result.error or ""}
            differs = trail_difference(records, asked)
            if differs is not None:
                why = f" (replay: {printable(result.error, 160)})" if result.error else ""
                raise _mismatch(f"{prefix}, audit trail {trail_path}: {differs}{why}", column="audit", **{**ids, "file": trail_path})
        elif rollout and env is not None:
            actions = _column_values(recorded.column("action"))
            ep_frames, images, status = _rollout_recording(env, spec, actions, {"prefix": prefix, "ids": ids})
            extra = {"status": status, "error": _replayed_error(status, row["error"], len(actions) - 1)}
        else:
            from pipeline.stages.episode import episode
            from pipeline.stages.record import encoded_frames

            ep_frames = episode(spec)
            images = encoded_frames(spec, ep_frames, typed.resolution, typed.jpeg_quality, typed.renderer)
        expected = frames_table(index, ep_frames, images, fps=typed.fps, obstacles=typed.obstacle_clearance)
        found = _first_difference(recorded, expected, expected.column_names)
        if found is None and recorded.num_rows != expected.num_rows:
            n = min(recorded.num_rows, expected.num_rows)
            found = (n, "frame_index", f": recorded {recorded.num_rows} frames, replay gives {expected.num_rows}")
        if found is not None:
            frame, column, detail = found
            raise _mismatch(f"{prefix}, frame {frame}, column {column}{detail}", frame=frame, column=column, **ids)
        if rollout:
            extra = {**(columns or {}), **extra}
        expected_row = episodes_table([episode_row(spec, ep_frames.grasp_angles, **extra)], rollout)
        recorded_row = episodes.filter(pa.array(episodes.column("episode_index").to_numpy() == index))
        found = _first_difference(recorded_row, expected_row, expected_row.column_names)
        if found is not None:
            _, column, detail = found
            raise _mismatch(f"{prefix}, episodes table, column {column}{detail}", frame=None, column=column,
                            **{**ids, "file": shard.files["episodes"].path})
        replayed.append((spec, ep_frames, images, extra))
        report_quietly(report, shard.first, shard.end, len(replayed), sum(f.num_frames for _, f, _, _ in replayed))
    if trail:
        episode_id = next(iter(trail))
        raise _mismatch(f"{root}: shard {stem}, audit trail {trail_path}: {len(trail[episode_id])} record(s) of episode "
                        f"{printable(episode_id, 60)}, which the shard does not hold", shard=stem, column="audit",
                        file=trail_path)

    with tempfile.TemporaryDirectory(prefix="dyana-replay-") as scratch:
        with ShardWriter(scratch, shard.first, shard.end, settings, rollout=rollout) as writer:
            for spec, ep_frames, images, extra in replayed:
                options: dict[str, Any] = {k: (v if k == "privileged" else (v or None)) for k, v in extra.items()}
                writer.add_episode(spec, ep_frames, images, **options)
        for kind, record in shard.files.items():
            again = writer.result.files[kind]
            if again.sha256 != record.sha256:  # the file on disk matches record.sha256 (checked above)
                raise _mismatch(
                    f"{root}: shard {stem}: {record.path} differs from the replayed shard's "
                    f"(sha256 {again.sha256[:12]}… instead of {record.sha256[:12]}…) although every column matches",
                    shard=stem, column=kind, file=record.path,
                )
    return sum(f.num_frames for _, f, _, _ in replayed)


def private_seed(root: object, manifest: Manifest, test_seed: str | None) -> TestSeed | None:
    """The private seed a run was drawn from (None for a public run), checked against the
    hash its manifest records; SpecError when it is missing, wrong, or given for a public run."""
    where = f"{root}/{MANIFEST_NAME}"
    record = manifest.extra.get(HELD_OUT_KEY)
    if record is None:
        if test_seed is not None:
            raise SpecError(f"{where}: this run was drawn from its slice's public seed; replay it without --test-seed")
        return None
    if test_seed is None:
        raise SpecError(f"{where}: this run's episodes were drawn from a private test seed; replaying it needs that "
                        "seed (--test-seed-file FILE, or --test-seed SECRET)")
    seed = matching(test_seed, record, where)
    if seed.slice_name != manifest.slice:
        raise SpecError(f"{where}: test_seed is salted for {printable(seed.slice_name, 40)}, the run is of {manifest.slice}")
    return seed


def drawn_specs(seed: TestSeed, protocol: EvalProtocol, first: int, end: int) -> list[EpisodeSpec]:
    """The specs a privately drawn run's episodes ``[first, end)`` hold (disturbed under ``disturb``)."""
    specs = private_specs(seed, first, end)
    return [disturbed_spec(spec)[0] for spec in specs] if protocol.disturb else specs


def replay(
    path: str | os.PathLike[str],
    shards: Sequence[int] | None = None,
    on_shard: Callable[[ShardRecord], None] | None = None,
    test_seed: str | None = None,
) -> ReplayReport:
    """Re-execute a built slice or a run (``shards``: only those first-episode indices);
    a run drawn from a private seed needs it (``test_seed``), and its stored specs must be
    the ones that seed draws."""
    folder = open_folder(path, verify="sha256")
    manifest, rollout = folder.manifest, folder.rollout
    seed = private_seed(folder.root, manifest, test_seed)
    renderer = check_rebuildable(folder.root, manifest)
    for record in manifest.audit or ():
        try:
            check_file(folder.root, record, "sha256")
        except ShardError as exc:
            raise ShardError(f"{exc} (the audit trail changed since the run)") from None
    raise_first(path, stray_files(folder.root, manifest))
    settings = recorded_settings(folder.root, manifest.settings)
    chosen = list(folder.shards)
    if shards is not None:
        if not isinstance(shards, (list, tuple, range, set, frozenset)) or any(
                isinstance(s, bool) or not isinstance(s, int) for s in shards):
            raise SpecError(f"shards must be a list of shards' first episode indices, got {shorten(repr(shards))}")
        wanted = set(shards)
        chosen = [s for s in chosen if s.record.first in wanted]
    env = None
    protocol = EvalProtocol.from_dict(settings.protocol)
    if rollout:
        if protocol.realtime:
            raise ShardError(
                f"{folder.root}: a real-time run (settings.protocol.realtime) depends on the machine's timing "
                "and cannot be replayed byte for byte"
            )
        # the recorded specs are the disturbed ones already: no second disturbance
        env = loop_env(settings.resolution, settings.jpeg_quality, dataclasses.replace(protocol, disturb=False),
                       renderer=renderer)
    audited = audited_replay(folder.root, manifest) if rollout else None
    columns = rollout_columns(folder.root, manifest, audited) if rollout else None
    episodes = frames = 0
    try:
        for shard in chosen:
            drawn = None if seed is None else drawn_specs(seed, protocol, shard.record.first, shard.record.end)
            try:
                frames += replay_shard(shard, manifest.settings, env, audited, columns=columns, drawn=drawn)
            except ReplayMismatch as exc:
                raise _mismatch(f"{exc}{mismatch_note(manifest.versions)}",
                                **{key: getattr(exc, key, None) for key in MISMATCH_WHERE}) from None
            episodes += shard.record.num_episodes
            if on_shard is not None:
                on_shard(shard.record)
    finally:
        if env is not None:
            env.close()
    return ReplayReport(
        path=os.fspath(path),
        slice=manifest.slice,
        kind="rollouts" if rollout else "slice",
        shards=len(chosen),
        episodes=episodes,
        frames=frames,
    )
