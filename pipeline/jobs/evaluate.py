"""`pipeline eval`: a policy in the loop on a slice's episodes, recorded as rollout shards.

The run folder (RUN, or an ``s3://`` URL) has the layout of a built slice: ``frames/``,
``episodes/`` and ``mcap/`` (unless ``--formats parquet``) with one file per shard each
(the episodes table adds ``policy``, ``status``, ``error``) and ``RUN/catalog.json``, whose ``policy`` key marks it as rollouts. Shards run
through :func:`pipeline.jobs.runner.run_job` as a build's do (and resume the same way); each task makes its own policy
through :mod:`pipeline.policy_registry` (a built-in name or a ``module:callable`` ref is
resolved inside the worker, a ``ws://`` URL is connected from the worker; a kind with an
audit trail, the VLM's, keeps it beside the shards). After an episode fails the worker discards that policy (a hung
thread or a broken connection may still hold it) and makes a fresh one.

The recorded bytes depend only on the slice, the settings and the policy's actions: not
on the number of workers, the transport (in-process or WebSocket), machine load or
timing. A per-call deadline is opt-in (``--deadline``, recorded in the manifest as
``deadline_s``; it then decides which slow calls fail); without one, only a call that
never returns meets the generous watchdog and fails its episode as "hung".
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from catalog.manifest import Manifest, load_manifest, manifest_path
from catalog.storage import as_location, is_url
from generators.heldout import MANIFEST_KEY as HELD_OUT_KEY
from generators.heldout import TestSeed, derive, private_specs
from pipeline.jobs.audit import read_audit, stamped, write_audit
from pipeline.jobs.build import BuildSettings
from pipeline.jobs.engine import refuse_export_folder
from pipeline.jobs.object_store import run_job_at
from pipeline.jobs.runner import Job, ShardTask, default_workers, shard_ranges
from pipeline.jobs.sink import ShardSink
from pipeline.loop.conditions import EvalProtocol
from pipeline.loop.fault_text import split_reason
from pipeline.loop.rollout import WATCHDOG_S, check_seconds, run_episode
from pipeline.loop.wrappers import loop_env
from pipeline.policies.base import Observation, Policy, Task
from pipeline.policy_registry import (
    Audited,
    Config,
    OpenOptions,
    PolicyKind,
    Timed,
    close_policy,
    describe_policy,
    kind_named,
    kind_of,
    open_policy,
)
from pipeline.remote.sandbox import Seal, sealing
from schemas.errors import AllEpisodesFailed, PolicyError, SpecError
from schemas.formats import ALL_FORMATS, parse_formats
from schemas.names import printable, shorten
from schemas.renderers import DEFAULT_RENDERER, check_renderer, dataset_version_of
from schemas.runs import is_run

DEFAULT_SHARD_SIZE = 32


@dataclass(frozen=True)
class EvalSettings:
    """Everything that determines a run's bytes besides the specs: the build settings
    (in ``catalog.json``'s ``settings``), the policy, whether it is privileged (it reads
    the ground-truth spec) and the opt-in deadline (its top-level keys; ``deadline_s``
    null means none: results then never depend on timing)."""

    build: BuildSettings
    slice_name: str
    policy_ref: str
    policy_name: str
    privileged: bool
    deadline_s: float | None
    isolate: bool = True
    #: The policy kind's configuration (a ``vlm:URL`` ref's settings, a ``lerobot:PATH`` ref's device), recorded in the manifest.
    config: Config | None = None
    #: The evaluation protocol (latency, perturbation, repeat), in ``settings.protocol``.
    protocol: EvalProtocol = EvalProtocol()
    #: The policy's kind (:mod:`pipeline.policy_registry`).
    kind: str = "builtin"
    #: A held-out run's seal for a user's policy (:mod:`pipeline.remote.sandbox`); not recorded.
    seal: Seal | None = None

    @property
    def call_timeout_s(self) -> float:
        return WATCHDOG_S if self.deadline_s is None else self.deadline_s

    @property
    def policy_kind(self) -> PolicyKind:
        return kind_named(self.kind)

    def open_options(self) -> OpenOptions:
        return OpenOptions(self.call_timeout_s, self.isolate, self.config, self.seal)

    def extra(self) -> dict[str, Any]:
        """The manifest's rollout keys (the policy's name, not its ref: a restarted server
        may move port, and the same run resumes)."""
        extra: dict[str, Any] = {"policy": self.policy_name, "privileged": self.privileged, "deadline_s": self.deadline_s}
        return extra | self.policy_kind.manifest(self.config)


class Unavailable:
    """Stands in for a policy that could not be made: its episode records the reason."""

    action_horizon = 1
    privileged = False

    def __init__(self, name: str, reason: str) -> None:
        self.name, self.reason = name, reason

    def reset(self, task: Task) -> None:
        raise PolicyError(self.reason)

    def act(self, obs: Observation) -> np.ndarray:
        raise PolicyError(self.reason)


def fresh_policy(settings: EvalSettings) -> Policy:
    """The run's policy, made anew in the worker; an :class:`Unavailable` when it cannot be."""
    try:
        return open_policy(settings.policy_ref, settings.open_options())
    except PolicyError as exc:
        return Unavailable(settings.policy_name, str(exc))
    except Exception as exc:
        return Unavailable(settings.policy_name, f"cannot make the policy: {type(exc).__name__}: {exc}")


def eval_shard(task: ShardTask, settings: EvalSettings, sink: ShardSink) -> dict[str, Any]:
    """Worker side: roll out one shard's episodes and write them where the run's output is
    (:mod:`pipeline.jobs.sink`); the record and timing."""
    with sink.writing() as run_dir:
        return _eval_shard(task, settings, run_dir)


def _eval_shard(task: ShardTask, settings: EvalSettings, run_dir: Path) -> dict[str, Any]:
    from catalog.shard import ShardWriter

    env = loop_env(settings.build.resolution, settings.build.jpeg_quality, settings.protocol,
                   renderer=settings.build.renderer)
    stats: dict[str, Any] = {"episodes": 0, "errors": 0, "steps": 0, "calls": 0, "policy_s": 0.0, "remote": None}
    policy: Policy | None = None
    audit: list[dict[str, Any]] = []
    start = time.perf_counter()
    try:
        with ShardWriter(run_dir, task.first, task.end, settings.build.as_dict(), rollout=True) as writer:
            for spec in task.specs():
                if policy is None:
                    policy = fresh_policy(settings)
                result = run_episode(env, policy, spec, settings.deadline_s)
                if isinstance(policy, Audited):
                    audit.extend(stamped(policy.take_audit(), result.spec.episode_id))
                writer.add_episode(
                    result.spec,
                    result.frames,
                    result.images,
                    policy=settings.policy_name,
                    privileged=settings.privileged,
                    status=result.status,
                    error=result.error or None,
                )
                stats["episodes"] += 1
                stats["steps"] += result.steps
                stats["calls"] += result.calls
                stats["policy_s"] += result.policy_s
                if not result.ok:
                    stats["errors"] += 1
                    _retire(policy, stats)
                    policy = None
    finally:
        _retire(policy, stats)
        env.close()
    audit_dir = settings.policy_kind.audit_dir
    if audit_dir is not None:
        write_audit(run_dir / audit_dir, task.first, task.end, audit)
    stats["seconds"] = time.perf_counter() - start
    return {"record": writer.result.to_dict(), "stats": stats}


def _retire(policy: Policy | None, stats: dict[str, Any]) -> None:
    """Close a policy, keeping its remote timing (if any) in ``stats``."""
    if policy is None:
        return
    if isinstance(policy, Timed) and policy.timing()["calls"]:
        stats["remote"] = _merge_timing(stats["remote"], policy.timing())
    close_policy(policy)


def _merge_timing(total: dict | None, part: dict) -> dict:
    if total is None:
        return dict(part)
    calls = total["calls"] + part["calls"]
    merged = {"calls": calls, "max_round_trip_ms": max(total["max_round_trip_ms"], part["max_round_trip_ms"])}
    for key in ("round_trip_ms", "server_ms"):
        merged[key] = (total[key] * total["calls"] + part[key] * part["calls"]) / max(calls, 1)
    return merged


#: Characters of an error reason (or traceback line) the summary prints.
REASON_CHARS = 300


@dataclass
class EvalSummary:
    """Quick counts over a run's files (``scoring eval RUN`` gives the paper's metrics):
    localized / grasped use the scoring definitions, over the ``ok`` episodes."""

    policy: str
    slice: str
    episodes: int
    frames: int
    errors: int
    localized: int
    grasped: int
    error_reasons: list[tuple[int, str]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def lines(self, tracebacks: bool = False) -> list[str]:
        """The summary; peer text made printable. ``tracebacks`` adds each error's traceback
        lines (kept in the error record; printed with ``--in-process``)."""
        n = max(self.episodes, 1)
        out = [
            f"evaluated {printable(self.policy)} on {self.slice}: {self.episodes} episodes, {self.frames} frames, "
            f"{self.errors} error(s)",
            f"  localized {self.localized}/{self.episodes} ({100.0 * self.localized / n:.1f}%), "
            f"grasped {self.grasped}/{self.episodes} ({100.0 * self.grasped / n:.1f}%)  "
            "(quick counts; `scoring eval RUN` for the metrics)",
        ]
        for index, reason in self.error_reasons[:5]:
            head, frames = split_reason(reason)
            out.append(f"  error in episode {index}: {printable(head, REASON_CHARS)}")
            out.extend(f"    {printable(line, REASON_CHARS)}" for line in (frames if tracebacks else ()))
        if len(self.error_reasons) > 5:
            out.append(f"  ... and {len(self.error_reasons) - 5} more error(s)")
        return out


def check_some_episode_ran(summary: EvalSummary) -> None:
    """AllEpisodesFailed (exit 3) when every episode of a written run failed, with the first reason."""
    if summary.episodes and len(summary.error_reasons) >= summary.episodes:
        index, reason = summary.error_reasons[0]
        raise AllEpisodesFailed(
            f"every episode failed ({summary.episodes} of {summary.episodes}); the first, episode {index}: "
            f"{printable(split_reason(reason)[0], REASON_CHARS)}"
        )


def summarize(run_dir: str | Path) -> EvalSummary:
    """Count episodes, errors, localizations and grasps of a run, through :mod:`scoring`
    (the same reading, checks and event definitions as ``scoring eval``)."""
    from scoring.io import load_run
    from scoring.report import score_run

    root = as_location(run_dir)
    manifest = load_manifest(root)
    if not is_run(manifest.extra):
        raise SpecError(f"{root}: not a rollout run (catalog.json has no policy)")
    data = load_run(root)
    overall = score_run(data).overall
    reasons = [
        (int(index), str(message))
        for index, message, failed in zip(data.episode_index, data.error_message, data.error)
        if failed
    ]
    return EvalSummary(
        policy=str(manifest.extra["policy"]),
        slice=manifest.slice + (" (drawn from a private test seed)" if HELD_OUT_KEY in manifest.extra else ""),
        episodes=manifest.episodes,
        frames=manifest.frames,
        errors=overall.errors,
        localized=overall.localized,
        grasped=overall.grasped,
        error_reasons=reasons,
    )


def evaluate(
    policy_ref: str,
    slice_name: str,
    out: str | Path,
    *,
    episodes: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    deadline_s: float | None = None,
    resolution: int = 224,
    shard_size: int = DEFAULT_SHARD_SIZE,
    progress: bool = True,
    summary: bool = True,
    stream: TextIO | None = None,
    overwrite: bool = False,
    isolate: bool = True,
    config: dict[str, Any] | None = None,
    protocol: EvalProtocol | None = None,
    formats: str | tuple[str, ...] = ALL_FORMATS,
    require_success: bool = False,
    test_seed: str | None = None,
    renderer: str = DEFAULT_RENDERER,
    test_seed_file: str | None = None,
) -> Manifest:
    """Evaluate ``policy_ref`` on the first ``episodes`` of ``slice_name`` into ``out``
    (RUN/catalog.json + shards); prints a summary to ``stream`` (stdout) and returns the manifest.

    ``workers`` defaults to one per core; ``workers=0`` (without a scheduler) runs the
    shards one after another in this process, without Dask: same bytes, for debugging
    and tests. A folder holding another run is refused unless ``overwrite``. A user's
    ``module:callable`` runs in a child process per worker (``isolate``; same bytes), so
    that its crash or exit fails only its episode. ``protocol`` (latency, perturbation,
    repeat; :mod:`pipeline.loop.conditions`) is recorded in ``settings.protocol``. ``config``
    is the policy kind's configuration (:mod:`pipeline.policy_registry`): a ``vlm:URL``
    policy's ``--model`` and ``--vlm-*`` settings, a ``lerobot:PATH`` policy's device;
    kinds that take none refuse it. With
    ``require_success``, a run in which every episode failed raises AllEpisodesFailed after
    it is written and summarised (the run is read once for both). ``test_seed`` (a secret)
    draws a held-out slice's episodes from it instead of the public seed
    (:mod:`generators.heldout`): the manifest keeps its hash only (key ``test_seed``), and a
    ``module:callable`` policy runs sealed (:mod:`pipeline.remote.sandbox`), never seeing
    ``test_seed_file`` (the file the secret was read from) or the run folder.
    ``renderer`` (:mod:`schemas.renderers`) draws the frames and decides the run's dataset
    version, as for a build."""
    from generators.encode import JPEG_QUALITY
    from schemas.slices import get_slice

    version = dataset_version_of(check_renderer(renderer))
    kind = kind_of(policy_ref)
    run_dir = as_location(out, "out")
    if deadline_s is not None:
        try:
            deadline_s = check_seconds("--deadline", deadline_s)
        except PolicyError as exc:
            raise SpecError(str(exc)) from None
    definition = get_slice(slice_name)
    private = None if test_seed is None else derive(test_seed, slice_name)
    if definition.union:
        raise SpecError(f"{slice_name} is the union of {', '.join(definition.parts)}: evaluate on one of them or test-1k")
    total = definition.episodes if episodes is None else episodes
    if isinstance(total, bool) or not isinstance(total, int) or not 1 <= total <= definition.episodes:
        raise SpecError(f"--episodes must be in [1, {definition.episodes}] for {slice_name}, got {shorten(repr(total))}")
    if protocol is not None and not isinstance(protocol, EvalProtocol):
        raise SpecError(f"protocol must be a pipeline.loop.conditions.EvalProtocol or None, got {shorten(repr(protocol))}")
    protocol = protocol or EvalProtocol()
    build_settings = BuildSettings(resolution=resolution, jpeg_quality=JPEG_QUALITY,
                                   obstacle_clearance=definition.may_hold_obstacles,
                                   protocol=None if protocol.plain else protocol.to_dict(),
                                   formats=parse_formats(formats), dataset_version=version)
    ranges = shard_ranges(total, shard_size)
    if not is_url(out):
        refuse_export_folder(run_dir, "run")
    config = kind.configure(policy_ref, config)
    seal = sealing(kind.name, private, isolate, test_seed_file, None if is_url(out) else str(run_dir))
    options = OpenOptions(WATCHDOG_S if deadline_s is None else deadline_s, bool(isolate), config, seal)
    name, privileged = describe_policy(policy_ref, options)
    if kind.check is not None:  # e.g. an unreachable VLM endpoint: one line now, not a failed run
        kind.check(config)
    settings = EvalSettings(build_settings, slice_name, policy_ref, name, privileged, deadline_s, bool(isolate), config,
                            protocol, kind.name, seal)
    if is_url(out) and kind.audit_dir is not None:
        raise SpecError(f"--out {str(out)[:60]}: a {kind.name} run keeps its audit trail on local disk; evaluate it locally")
    job = Job(
        folder=Path("/nonexistent-remote-job") if is_url(out) else run_dir,
        slice_name=slice_name,
        seed=definition.seed if private is None else None,
        settings=build_settings.as_dict(),
        extra=settings.extra() | ({} if private is None else {HELD_OUT_KEY: private.record()}),
        tasks=tuple(_shard_task(slice_name, first, end, private) for first, end in ranges),
        task_fn=eval_shard,
        payload=settings,
        verb="evaluated",
        key_prefix="eval",
        audit_dir=kind.audit_dir,
    )
    timing: dict[str, Any] = {"episodes": 0, "steps": 0, "calls": 0, "policy_s": 0.0, "remote": None}

    def on_result(result: dict) -> None:
        stats = result["stats"]
        for key in ("episodes", "steps", "calls", "policy_s"):
            timing[key] += stats[key]
        if stats["remote"] is not None:
            timing["remote"] = _merge_timing(timing["remote"], stats["remote"])

    start = time.monotonic()
    result = run_job_at(
        job,
        out,
        workers=default_workers() if workers is None else workers,
        scheduler=scheduler,
        progress=progress,
        overwrite=overwrite,
        on_result=on_result,
    )
    manifest, up_to_date = result.manifest, result.up_to_date
    elapsed = time.monotonic() - start
    counts = summarize(run_dir) if summary or require_success else None
    if summary and counts is not None:
        out_stream = sys.stdout if stream is None else stream
        if up_to_date:
            print(f"{run_dir}: up to date (the same run is complete; --overwrite to run it again)", file=out_stream)
        for line in counts.lines(tracebacks=not isolate):
            print(line, file=out_stream)
        if kind.audit_dir is not None:
            trail, records = run_dir / kind.audit_dir, read_audit(run_dir, manifest.audit or ())
            summary_line = kind.summarize_audit(records) if kind.summarize_audit else f"{len(records)} records"
            print(f"  {kind.name}: {summary_line}; trail in {trail}", file=out_stream)
        for line in _timing_lines(timing, elapsed):
            print(line, file=out_stream)
        print(f"  -> {manifest_path(run_dir)} (hash {manifest.hash[:16]})", file=out_stream, flush=True)
    if require_success and counts is not None:
        check_some_episode_ran(counts)
    return manifest


def _shard_task(slice_name: str, first: int, end: int, private: TestSeed | None) -> ShardTask:
    """A shard of the public slice (its workers draw the specs), or of the privately drawn
    one (drawn here: the workers never see the seed)."""
    if private is None:
        return ShardTask(slice_name, first, end)
    return ShardTask(slice_name, first, end, tuple(spec.to_json() for spec in private_specs(private, first, end)))


def _timing_lines(timing: dict[str, Any], elapsed: float) -> Sequence[str]:
    if not timing["episodes"]:
        return []
    lines = [
        f"  time: {elapsed:.1f} s, {timing['episodes'] / max(elapsed, 1e-9):.2f} episodes/s, "
        f"{timing['steps'] / max(elapsed, 1e-9):.1f} steps/s; policy {1000.0 * timing['policy_s'] / max(timing['calls'], 1):.2f} ms per act"
    ]
    remote = timing["remote"]
    if remote is not None:
        lines.append(
            f"  transport: {remote['round_trip_ms']:.2f} ms round trip per act (server {remote['server_ms']:.2f} ms, "
            f"worst {remote['max_round_trip_ms']:.1f} ms)"
        )
    return lines
