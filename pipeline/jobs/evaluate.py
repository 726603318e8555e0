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

import dataclasses
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TextIO

from catalog.store.manifest import Manifest, load_manifest, manifest_path
from catalog.store.records import ShardRecord
from catalog.store.storage import as_location
from catalog.tables.partial import PartialShard
from catalog.tables.reader import ShardReader
from catalog.tables.stats import written_partial
from generators.heldout import MANIFEST_KEY as HELD_OUT_KEY
from generators.heldout import TestSeed, derive, private_specs
from pipeline.jobs.audit import read_audit, stamped, write_audit
from pipeline.jobs.progress import announcement
from pipeline.jobs.runner import PARTIAL_STATS, Job, JobResult, ShardTask, run_job, shard_ranges
from pipeline.jobs.sink import ShardSink
from pipeline.jobs.spec import JobSpec, Storage, job_spec
from pipeline.jobs.staged import Recorded, held_result, staged_episode, staged_result
from pipeline.jobs.tasks import STAGED_EPISODES
from pipeline.loop.conditions import EvalProtocol
from pipeline.loop.deadlines import call_timeout
from pipeline.loop.fault_text import split_reason
from pipeline.loop.rollout import run_episode
from pipeline.loop.wrappers import settings_env
from pipeline.policies.base import Policy
from pipeline.policy_registry import (
    Audited,
    Config,
    OpenOptions,
    PolicyKind,
    Timed,
    Unavailable,
    close_policy,
    describe_policy,
    kind_named,
    kind_of,
    open_policy,
)
from pipeline.remote.sandbox import Seal, configured, sealing
from schemas.errors import AllEpisodesFailed, DyanaError, PolicyError, SpecError
from schemas.names import printable
from schemas.runs import is_run
from schemas.settings import BuildSettings
from schemas.versions import HAND_MODEL

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
    #: Where the episodes were staged when they ran elsewhere (:mod:`pipeline.jobs.staged`); not recorded.
    recorded: str | None = None

    @property
    def call_timeout_s(self) -> float:
        return call_timeout(self.deadline_s)

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
        resumable = settings.recorded is None and settings.policy_kind.episodic
        return _eval_shard(task, settings, run_dir, task.partial(run_dir) if resumable else None)


def _eval_shard(task: ShardTask, settings: EvalSettings, run_dir: Path, partial: PartialShard | None) -> dict[str, Any]:
    from catalog.tables.shard import ShardWriter

    env = settings_env(settings.build)
    stats: dict[str, Any] = {"episodes": 0, "errors": 0, "steps": 0, "calls": 0, "policy_s": 0.0, "remote": None,
                             "staged": 0}
    policy: Policy | None = None
    audit: list[dict[str, Any]] = []
    start = time.perf_counter()
    try:
        with ShardWriter(run_dir, task.first, task.end, settings.build.to_dict(), rollout=True) as writer:
            for spec in task.specs():
                held = None if partial is None else held_result(partial.load(spec))
                if held is not None:
                    result, records = held
                elif settings.recorded is not None:
                    result, records = staged_result(settings.recorded, spec), []
                else:
                    policy = fresh_policy(settings) if policy is None else policy
                    result = run_episode(env, policy, spec, settings.deadline_s)
                    records = stamped(policy.take_audit(), result.spec.episode_id) if isinstance(policy, Audited) else []
                    if partial is not None:
                        partial.save(spec, staged_episode(result, records))
                audit.extend(records)
                writer.add_episode(result.spec, result.frames, result.images, policy=settings.policy_name,
                                   privileged=settings.privileged, status=result.status, error=result.error or None)
                if held is not None:  # taken from an interrupted run: no time spent on it now
                    stats["staged"] += 1
                    continue
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
    if partial is not None:
        partial.remove()
    audit_dir = settings.policy_kind.audit_dir
    if audit_dir is not None:
        write_audit(run_dir / audit_dir, task.first, task.end, audit)
    stats["seconds"] = time.perf_counter() - start
    # while the files are on this host: what the driver's statistics and summary need
    out = {"record": writer.result.to_dict(), "stats": stats, PARTIAL_STATS: written_partial(run_dir, writer.result),
           STAGED_EPISODES: stats["staged"]}
    try:
        out[COUNTS] = shard_counts(run_dir, writer.result, settings)
    except (DyanaError, ValueError):  # unscorable: the driver's read-back of the run says why, as before
        pass
    return out


#: The task result's key of a shard's summary counts (:func:`shard_counts`).
COUNTS = "counts"


def shard_counts(run_dir: Path, record: ShardRecord, settings: EvalSettings) -> dict[str, Any]:
    """The summary's counts of one written shard (errors, localized, grasped: sums over its
    episodes, so shards add up) and its failed episodes' reasons, read and scored as
    :func:`summarize` reads and scores a whole run."""
    from scoring.io import read_shards
    from scoring.report import score_run

    shard = ShardReader(run_dir, record, rollout=True, verify="size")
    data = read_shards(run_dir, [shard], settings.slice_name, settings.build.to_dict(), rollout=True)
    overall = score_run(data).overall
    reasons = [[int(i), str(m)] for i, m, failed in zip(data.episode_index, data.error_message, data.error) if failed]
    return {"errors": overall.errors, "localized": overall.localized, "grasped": overall.grasped,
            "error_reasons": reasons}


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


def summary_of(manifest: Manifest, kept: Sequence[Mapping[str, Any]]) -> EvalSummary | None:
    """The summary from the shards' :func:`shard_counts` (what the tasks returned, or the
    resume state kept), None when a shard's are missing (an up-to-date run, an older state)."""
    if not kept or any(COUNTS not in k for k in kept):
        return None
    counts = [k[COUNTS] for k in kept]
    return EvalSummary(
        policy=str(manifest.extra["policy"]),
        slice=manifest.slice + (" (drawn from a private test seed)" if HELD_OUT_KEY in manifest.extra else ""),
        episodes=manifest.episodes, frames=manifest.frames,
        errors=sum(c["errors"] for c in counts), localized=sum(c["localized"] for c in counts),
        grasped=sum(c["grasped"] for c in counts),
        error_reasons=[(int(i), str(m)) for c in counts for i, m in c["error_reasons"]],
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


def evaluate(policy_ref: str, slice_name: str, out: str | Path, **options: Any) -> Manifest:
    """Evaluate ``policy_ref`` on the first ``episodes`` of ``slice_name`` into ``out``
    (RUN/catalog.json + shards); prints a summary to ``stream`` (stdout) and returns the manifest.

    The keyword options are the CLI's flags (:func:`pipeline.jobs.spec.job_spec`) and the
    summary's: ``episodes``, ``shard_size`` (default 32), ``resolution``, ``renderer``
    (which draws the frames and decides the run's dataset version, as for a build),
    ``formats``, ``workers`` (default one per core; ``workers=0`` without a scheduler runs
    the shards one after another in this process, without Dask: same bytes, for debugging
    and tests), ``scheduler``, ``progress``, ``overwrite`` (a folder holding another run is
    refused without it), and

    - ``isolate`` (True): a user's ``module:callable`` runs in a child process per worker
      (same bytes), so that its crash or exit fails only its episode;
    - ``deadline_s``: the opt-in seconds per policy call, recorded in the manifest;
    - ``protocol`` (latency, perturbation, repeat; :mod:`pipeline.loop.conditions`), recorded
      in ``settings.protocol``;
    - ``config``: the policy kind's configuration (:mod:`pipeline.policy_registry`): a
      ``vlm:URL`` policy's ``--model`` and ``--vlm-*`` settings, a ``lerobot:PATH`` policy's
      device; kinds that take none refuse it;
    - ``test_seed`` (a secret): draws a held-out slice's episodes from it instead of the
      public seed (:mod:`generators.heldout`): the manifest keeps its hash only (key ``test_seed``);
    - ``recorded`` (:class:`~pipeline.jobs.staged.Recorded`): the episodes ran elsewhere
      (LeRobot's own loop, :mod:`pipeline.envhub`) and are written from their staged results;
    - ``summary`` (True) and ``stream`` (stdout): where the summary is printed;
    - ``require_success``: a run in which every episode failed raises AllEpisodesFailed
      after it is written and summarised (the run is read once for both).

    :func:`run_eval` takes the :class:`~pipeline.jobs.spec.JobSpec`."""
    recorded = options.pop("recorded", None)
    report = Report(**{k: options.pop(k) for k in ("summary", "stream", "require_success") if k in options})
    spec = job_spec(slice_name, out, options, shard_size=DEFAULT_SHARD_SIZE, policy_ref=policy_ref)
    return run_eval(spec, report, recorded)


@dataclass(frozen=True)
class Report:
    """What an eval prints: the ``summary`` (to ``stream``, default stdout), and whether a
    run whose every episode failed is an error (``require_success``: AllEpisodesFailed)."""

    summary: bool = True
    stream: TextIO | None = None
    require_success: bool = False


def run_eval(spec: JobSpec, report: Report | None = None, recorded: Recorded | None = None) -> Manifest:
    """Run an eval's :class:`~pipeline.jobs.spec.JobSpec` (its ``policy`` part set): the
    run's manifest; the summary as ``report`` says (:func:`evaluate`). With ``recorded``
    the episodes already ran elsewhere: they are written from its staged results."""
    from schemas.slices import get_slice

    report = Report() if report is None else report
    selection, storage, choice = spec.selection, spec.storage, spec.policy
    if choice is None:
        raise SpecError("an eval needs a policy (JobSpec.policy)")
    slice_name = selection.slice_name
    if slice_name is None:
        raise SpecError("an eval needs --slice NAME")
    kind = kind_of(choice.ref)
    definition = get_slice(slice_name)
    private = None if selection.test_seed is None else derive(selection.test_seed, slice_name)
    if definition.union:
        raise SpecError(f"{slice_name} is the union of {', '.join(definition.parts)}: evaluate on one of them or test-1k")
    total = selection.first_episodes(definition.episodes, slice_name)
    protocol = choice.protocol
    build_settings = dataclasses.replace(spec.settings, obstacle_clearance=definition.may_hold_obstacles,
                                         protocol=None if protocol.plain else protocol.to_dict(), hand_model=HAND_MODEL)
    ranges = shard_ranges(total, selection.shard_size)
    storage.refuse_export("run")
    shown = None if kind.sealed_files is None else kind.sealed_files(choice.ref)
    seal = sealing(shown, private, choice.isolate, selection.test_seed_file,
                   None if storage.remote else str(storage.folder))
    # A sealed kind's configuration may load its code (an SB3 zip): made sealed too, not beside the secret.
    config = kind.configure(choice.ref, choice.config) if seal is None else configured(seal, choice.ref, choice.config)
    options = OpenOptions(call_timeout(choice.deadline_s), choice.isolate, config, seal)
    name, privileged = describe_policy(choice.ref, options) if recorded is None else (recorded.name, recorded.privileged)
    if kind.check is not None and recorded is None:  # e.g. an unreachable VLM endpoint: one line now, not a failed run
        kind.check(config, build_settings.resolution)
    settings = EvalSettings(build_settings, slice_name, choice.ref, name, privileged, choice.deadline_s, choice.isolate,
                            config, protocol, kind.name, seal, None if recorded is None else recorded.folder)
    if storage.remote and kind.audit_dir is not None:
        raise SpecError(f"--out {str(storage.out)[:60]}: a {kind.name} run keeps its audit trail on local disk; "
                        "evaluate it locally")
    job = Job(
        slice_name=slice_name,
        seed=definition.seed if private is None else None,
        settings=build_settings.to_dict(),
        extra=settings.extra() | ({} if private is None else {HELD_OUT_KEY: private.record()}),
        tasks=tuple(_shard_task(slice_name, first, end, private) for first, end in ranges),
        task_fn=eval_shard,
        payload=settings,
        verb="evaluated",
        key_prefix="eval",
        audit_dir=kind.audit_dir,
        keep=(PARTIAL_STATS, COUNTS),
        about="" if spec.execution.say is None else announcement(
            f"evaluating {printable(name, 60)} on", slice_name + (" (held out)" if private else ""), total,
            selection.shard_size, build_settings.resolution, counted=False),
    )
    timing: dict[str, Any] = {"episodes": 0, "steps": 0, "calls": 0, "policy_s": 0.0, "remote": None}

    def on_result(result: dict) -> None:
        stats = result["stats"]
        for key in ("episodes", "steps", "calls", "policy_s"):
            timing[key] += stats[key]
        if stats["remote"] is not None:
            timing["remote"] = _merge_timing(timing["remote"], stats["remote"])

    start = time.monotonic()
    result = run_job(job, spec.execution, storage, on_result)
    _report(storage, settings, result, report, (timing, time.monotonic() - start))
    return result.manifest


def _report(storage: Storage, settings: EvalSettings, result: JobResult, report: Report,
            timing: tuple[dict[str, Any], float]) -> None:
    """Print the run's summary, as ``report`` says, and refuse a run whose every episode failed."""
    run_dir = as_location(storage.out, "out")
    manifest, up_to_date, kind = result.manifest, result.up_to_date, settings.policy_kind
    counts = None
    if report.summary or report.require_success:  # from the shards' results; read back only when none came
        counts = summary_of(manifest, result.kept) or summarize(run_dir)
    if report.summary and counts is not None:
        out_stream = sys.stdout if report.stream is None else report.stream
        if up_to_date:
            print(f"{run_dir}: up to date (the same run is complete; --overwrite to run it again)", file=out_stream)
        for line in counts.lines(tracebacks=not settings.isolate):
            print(line, file=out_stream)
        if kind.audit_dir is not None:
            trail, records = run_dir / kind.audit_dir, read_audit(run_dir, manifest.audit or ())
            summary_line = kind.summarize_audit(records) if kind.summarize_audit else f"{len(records)} records"
            print(f"  {kind.name}: {summary_line}; trail in {trail}", file=out_stream)
        for line in _timing_lines(*timing):
            print(line, file=out_stream)
        print(f"  -> {manifest_path(run_dir)} (hash {manifest.hash[:16]})", file=out_stream, flush=True)
    if report.require_success and counts is not None:
        check_some_episode_ran(counts)


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
