"""`pipeline eval`: a policy in the loop on a slice's episodes, recorded as rollout shards.

The run folder (RUN, or an ``s3://`` URL) has the layout of a built slice: ``frames/``,
``episodes/`` and ``mcap/`` (unless ``--formats parquet``) with one file per shard each
(the episodes table adds ``policy``, ``status``, ``error``) and ``RUN/catalog.json``, whose ``policy`` key marks it as rollouts. Shards run
through :func:`pipeline.jobs.runner.run_job` as a build's do (and resume the same way); each task makes its own policy: a built-in name or a
``module:callable`` ref is resolved inside the worker, a ``ws://`` URL is connected
from the worker. After an episode fails the worker discards that policy (a hung
thread or a broken connection may still hold it) and makes a fresh one.

The recorded bytes depend only on the slice, the settings and the policy's actions: not
on the number of workers, the transport (in-process or WebSocket), machine load or
timing. A per-call deadline is opt-in (``--deadline``, recorded in the manifest as
``deadline_s``; it then decides which slow calls fail); without one, only a call that
never returns meets the generous watchdog and fails its episode as "hung".
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from catalog.manifest import Manifest, load_manifest, manifest_path
from catalog.storage import as_location, is_url
from pipeline.jobs.build import BuildSettings
from pipeline.jobs.object_store import run_job_at
from pipeline.jobs.runner import Job, ShardTask, default_workers, shard_ranges
from pipeline.loop.conditions import EvalProtocol
from pipeline.loop.disturb import disturbed_spec
from pipeline.loop.rollout import WATCHDOG_S, check_seconds, run_episode
from schemas.errors import PolicyError, ShardError, SpecError
from schemas.formats import ALL_FORMATS, parse_formats

DEFAULT_SHARD_SIZE = 32
#: Extra seconds a remote policy's socket waits beyond the deadline or watchdog (the
#: runner's fires first and names the fault).
REMOTE_SLACK_S = 5.0


#: Where a VLM run's audit trail lives, beside the shards.
AUDIT_DIR = "vlm"


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
    #: A VLM policy's configuration (``vlm:URL`` refs), recorded in the manifest.
    vlm: dict[str, Any] | None = None
    #: The evaluation protocol (latency, perturbation, repeat), in ``settings.protocol``.
    protocol: EvalProtocol = EvalProtocol()

    @property
    def call_timeout_s(self) -> float:
        return WATCHDOG_S if self.deadline_s is None else self.deadline_s

    def extra(self) -> dict[str, Any]:
        """The manifest's rollout keys (the policy's name, not its ref: a restarted server
        may move port, and the same run resumes)."""
        extra: dict[str, Any] = {"policy": self.policy_name, "privileged": self.privileged, "deadline_s": self.deadline_s}
        if self.vlm is not None:
            extra["vlm"] = {k: v for k, v in self.vlm.items() if k != "url"} | {"url": _public_url(self.vlm["url"])}
        return extra


class _Unavailable:
    """Stands in for a policy that could not be made: its episode records the reason."""

    action_horizon = 1
    privileged = False

    def __init__(self, name: str, reason: str) -> None:
        self.name, self.reason = name, reason

    def reset(self, task: dict) -> None:
        raise PolicyError(self.reason)

    def act(self, obs: dict) -> np.ndarray:
        raise PolicyError(self.reason)


def _public_url(url: str) -> str:
    """A URL without user:password@ (credentials never reach a manifest)."""
    from urllib.parse import urlsplit, urlunsplit

    parts = urlsplit(url)
    host = parts.hostname or ""
    netloc = host + (f":{parts.port}" if parts.port else "")
    return urlunsplit((parts.scheme, netloc, parts.path, "", ""))


def is_vlm(ref: str) -> bool:
    return ref.startswith("vlm:")


def open_policy(ref: str, timeout_s: float = WATCHDOG_S, isolate: bool = True, vlm: dict[str, Any] | None = None) -> Any:
    """A fresh policy for ``ref``: RemotePolicy for ``ws://`` (its socket waits a little
    longer than ``timeout_s``); a user's ``module:callable`` in a child process unless
    ``isolate`` is False (:mod:`pipeline.remote.isolated`); else ``make_policy(ref)``."""
    from pipeline.remote.client import RemotePolicy, is_remote

    if is_vlm(ref):
        from pipeline.policies.vlm import VLMConfig, VLMPolicy

        if vlm is None:
            raise SpecError(f"policy {ref!r} needs a VLM configuration (--model NAME and the --vlm-* flags)")
        return VLMPolicy(VLMConfig(**vlm))
    if is_remote(ref):
        return RemotePolicy(ref, timeout_s=timeout_s + REMOTE_SLACK_S)
    if isolate and ":" in ref:
        from pipeline.remote.isolated import IsolatedPolicy

        return IsolatedPolicy(ref, timeout_s=timeout_s + REMOTE_SLACK_S)
    from pipeline.policies.base import make_policy

    return make_policy(ref)


def _close(policy: Any) -> None:
    close = getattr(policy, "close", None)
    if callable(close):
        try:
            close()
        except Exception:
            pass


def eval_shard(task: ShardTask, settings: EvalSettings, run_dir: str) -> dict[str, Any]:
    """Worker side: roll out one shard's episodes and write them; the record and timing."""
    from catalog.shard import ShardWriter
    from pipeline.loop.env import DyanaEnv

    env = DyanaEnv(resolution=settings.build.resolution, jpeg_quality=settings.build.jpeg_quality,
                   protocol=settings.protocol)
    stats: dict[str, Any] = {"episodes": 0, "errors": 0, "steps": 0, "calls": 0, "policy_s": 0.0, "remote": None}
    policy = None
    audit: list[dict[str, Any]] = []
    start = time.perf_counter()
    try:
        with ShardWriter(Path(run_dir), task.first, task.end, settings.build.as_dict(), rollout=True) as writer:
            for spec in task.specs():
                if policy is None:
                    try:
                        policy = open_policy(settings.policy_ref, settings.call_timeout_s, settings.isolate, settings.vlm)
                    except PolicyError as exc:
                        policy = _Unavailable(settings.policy_name, str(exc))
                    except Exception as exc:
                        policy = _Unavailable(settings.policy_name, f"cannot make the policy: {type(exc).__name__}: {exc}")
                if settings.protocol.disturb:
                    spec, _ = disturbed_spec(spec)
                result = run_episode(env, policy, spec, settings.deadline_s)
                take_audit = getattr(policy, "take_audit", None)
                if callable(take_audit):
                    audit.extend(take_audit())
                writer.add_episode(
                    spec,
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
        close_env = getattr(env, "close", None)
        if callable(close_env):
            close_env()
    if settings.vlm is not None:
        write_audit(Path(run_dir), task.first, task.end, audit)
    stats["seconds"] = time.perf_counter() - start
    return {"record": writer.result.to_dict(), "stats": stats}


def _retire(policy: Any, stats: dict[str, Any]) -> None:
    """Close a policy, keeping its remote timing (if any) in ``stats``."""
    from pipeline.remote.client import RemotePolicy
    from pipeline.remote.isolated import IsolatedPolicy

    if policy is None:
        return
    if isinstance(policy, (RemotePolicy, IsolatedPolicy)) and policy.timing()["calls"]:
        stats["remote"] = _merge_timing(stats["remote"], policy.timing())
    _close(policy)


def _merge_timing(total: dict | None, part: dict) -> dict:
    if total is None:
        return dict(part)
    calls = total["calls"] + part["calls"]
    merged = {"calls": calls, "max_round_trip_ms": max(total["max_round_trip_ms"], part["max_round_trip_ms"])}
    for key in ("round_trip_ms", "server_ms"):
        merged[key] = (total[key] * total["calls"] + part[key] * part["calls"]) / max(calls, 1)
    return merged


def describe_policy(
    ref: str, timeout_s: float = WATCHDOG_S, isolate: bool = True, vlm: dict[str, Any] | None = None
) -> tuple[str, bool]:
    """The policy's name and privileged flag, resolving ``ref`` once in the driver so that
    a bad name, an unimportable callable or an unreachable server fails before any work starts."""
    from pipeline.remote.client import is_remote

    try:
        policy = open_policy(ref, timeout_s, isolate, vlm)
    except PolicyError as exc:
        where = f"{ref}: " if is_remote(ref) else ""
        raise PolicyError(f"{where}{exc}") from None
    try:
        name = getattr(policy, "name", None)
        if not isinstance(name, str) or not name:
            raise SpecError(f"policy {ref!r} has no name (a Policy needs a non-empty str attribute name)")
        privileged = getattr(policy, "privileged", False)
        if not isinstance(privileged, bool):
            raise SpecError(f"policy {ref!r}: privileged must be True or False, got {privileged!r}")
        return name, privileged
    finally:
        _close(policy)


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

    def lines(self) -> list[str]:
        n = max(self.episodes, 1)
        out = [
            f"evaluated {self.policy} on {self.slice}: {self.episodes} episodes, {self.frames} frames, "
            f"{self.errors} error(s)",
            f"  localized {self.localized}/{self.episodes} ({100.0 * self.localized / n:.1f}%), "
            f"grasped {self.grasped}/{self.episodes} ({100.0 * self.grasped / n:.1f}%)  "
            "(quick counts; `scoring eval RUN` for the metrics)",
        ]
        for index, reason in self.error_reasons[:5]:
            out.append(f"  error in episode {index}: {reason}")
        if len(self.error_reasons) > 5:
            out.append(f"  ... and {len(self.error_reasons) - 5} more error(s)")
        return out


def summarize(run_dir: str | Path) -> EvalSummary:
    """Count episodes, errors, localizations and grasps of a run, through :mod:`scoring`
    (the same reading, checks and event definitions as ``scoring eval``)."""
    from scoring.io import load_run
    from scoring.report import score_run

    root = as_location(run_dir)
    manifest = load_manifest(root)
    if "policy" not in manifest.extra:
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
        slice=manifest.slice,
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
    vlm: dict[str, Any] | None = None,
    protocol: EvalProtocol | None = None,
    formats: str | tuple[str, ...] = ALL_FORMATS,
) -> Manifest:
    """Evaluate ``policy_ref`` on the first ``episodes`` of ``slice_name`` into ``out``
    (RUN/catalog.json + shards); prints a summary to ``stream`` (stdout) and returns the manifest.

    ``workers`` defaults to one per core; ``workers=0`` (without a scheduler) runs the
    shards one after another in this process, without Dask: same bytes, for debugging
    and tests. A folder holding another run is refused unless ``overwrite``. A user's
    ``module:callable`` runs in a child process per worker (``isolate``; same bytes), so
    that its crash or exit fails only its episode. ``protocol`` (latency, perturbation,
    repeat; :mod:`pipeline.loop.conditions`) is recorded in ``settings.protocol``."""
    from generators.encode import JPEG_QUALITY
    from schemas.slices import get_slice

    if not isinstance(policy_ref, str) or not policy_ref:
        raise SpecError(f"--policy must be a name, module:callable or ws://HOST:PORT, got {policy_ref!r}")
    if deadline_s is not None:
        try:
            deadline_s = check_seconds("--deadline", deadline_s)
        except PolicyError as exc:
            raise SpecError(str(exc)) from None
    definition = get_slice(slice_name)
    if definition.union:
        raise SpecError(f"{slice_name} is the union of {', '.join(definition.parts)}: evaluate on one of them or test-1k")
    total = definition.episodes if episodes is None else episodes
    if isinstance(total, bool) or not isinstance(total, int) or not 1 <= total <= definition.episodes:
        raise SpecError(f"--episodes must be in [1, {definition.episodes}] for {slice_name}, got {total!r}")
    protocol = protocol or EvalProtocol()
    build_settings = BuildSettings(resolution=resolution, jpeg_quality=JPEG_QUALITY,
                                   obstacle_clearance=definition.may_hold_obstacles,
                                   protocol=None if protocol.plain else protocol.to_dict(),
                                   formats=parse_formats(formats))
    ranges = shard_ranges(total, shard_size)
    if is_vlm(policy_ref):
        from pipeline.policies.vlm import VLMConfig

        vlm = VLMConfig(**{"url": policy_ref[len("vlm:"):], **(vlm or {})}).to_dict()
    elif vlm is not None:
        raise SpecError(f"--model and the --vlm-* flags are for vlm:URL policies, not {policy_ref!r}")
    name, privileged = describe_policy(policy_ref, WATCHDOG_S if deadline_s is None else deadline_s, isolate, vlm)
    settings = EvalSettings(build_settings, slice_name, policy_ref, name, privileged, deadline_s, bool(isolate), vlm,
                            protocol)
    if is_url(out) and vlm is not None:
        raise SpecError(f"--out {str(out)[:60]}: a VLM run keeps its audit trail on local disk; evaluate it locally")
    run_dir = as_location(out)
    job = Job(
        folder=Path("/nonexistent-remote-job") if is_url(out) else run_dir,
        slice_name=slice_name,
        seed=definition.seed,
        settings=build_settings.as_dict(),
        extra=settings.extra(),
        tasks=tuple(ShardTask(slice_name, first, end) for first, end in ranges),
        task_fn=eval_shard,
        payload=settings,
        verb="evaluated",
        key_prefix="eval",
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
    if vlm is not None:
        write_audit_index(run_dir)
    if summary:
        out_stream = sys.stdout if stream is None else stream
        if up_to_date:
            print(f"{run_dir}: up to date (the same run is complete; --overwrite to run it again)", file=out_stream)
        for line in summarize(run_dir).lines():
            print(line, file=out_stream)
        if vlm is not None:
            print(f"  vlm: {audit_summary(run_dir)}", file=out_stream)
        for line in _timing_lines(timing, elapsed):
            print(line, file=out_stream)
        print(f"  -> {manifest_path(run_dir)} (hash {manifest.hash[:16]})", file=out_stream, flush=True)
    return manifest


def audit_path(run_dir: Path, first: int, end: int) -> Path:
    return run_dir / AUDIT_DIR / f"audit-{first:06d}-{end:06d}.jsonl"


def write_audit(run_dir: Path, first: int, end: int, records: list[dict[str, Any]]) -> None:
    """A shard's VLM exchanges, one JSON object per line, written whole or not at all."""
    from catalog.atomic import atomic_write_text

    text = "".join(json.dumps(r, sort_keys=True, allow_nan=False) + "\n" for r in records)
    path = audit_path(run_dir, first, end)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)


def read_audit(run_dir: Path) -> list[dict[str, Any]]:
    """Every recorded VLM exchange of a run, in shard order."""
    records: list[dict[str, Any]] = []
    for path in sorted((run_dir / AUDIT_DIR).glob("audit-*.jsonl")):
        records += [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line]
    return records


def write_audit_index(run_dir: Path) -> None:
    """``vlm/index.json``: every audit file with its sha256 and size (what replay checks)."""
    from catalog.atomic import atomic_write_text
    from catalog.hashing import sha256_file

    files = {p.name: {"sha256": sha256_file(p), "size": p.stat().st_size}
             for p in sorted((run_dir / AUDIT_DIR).glob("audit-*.jsonl"))}
    atomic_write_text(run_dir / AUDIT_DIR / "index.json", json.dumps({"files": files}, indent=2, sort_keys=True) + "\n")


def check_audit_index(run_dir: Path) -> None:
    """Refuse a trail whose files are missing, extra or changed since the run."""
    from catalog.hashing import sha256_file

    index = Path(run_dir) / AUDIT_DIR / "index.json"
    if not index.is_file():
        raise ShardError(f"{index}: missing (the VLM run's audit trail has no index)")
    files = json.loads(index.read_text())["files"]
    present = sorted(p.name for p in (Path(run_dir) / AUDIT_DIR).glob("audit-*.jsonl"))
    if present != sorted(files):
        raise ShardError(f"{index}: lists {sorted(files)} but the folder holds {present}")
    for name, record in files.items():
        path = Path(run_dir) / AUDIT_DIR / name
        if path.stat().st_size != record["size"] or sha256_file(path) != record["sha256"]:
            raise ShardError(f"{path}: changed since the run (sha256 differs from {index.name})")


def audit_summary(run_dir: Path) -> str:
    """Counts of each exchange outcome, tokens and latency, from the audit trail."""
    from pipeline.policies.vlm import OUTCOMES

    records = read_audit(run_dir)
    counts = {k: sum(1 for r in records if r["outcome"] == k) for k in OUTCOMES}
    prompt = sum(r["reply"]["usage"]["prompt_tokens"] or 0 for r in records)
    completion = sum(r["reply"]["usage"]["completion_tokens"] or 0 for r in records)
    latency = sorted(r["reply"]["latency_ms"] for r in records)
    median = latency[len(latency) // 2] if latency else 0.0
    faults = ", ".join(f"{k} {v}" for k, v in counts.items() if k != "ok")
    return (f"{len(records)} queries, {counts['ok']} answered ({faults}); {prompt} prompt + {completion} completion "
            f"tokens; median latency {median:.0f} ms; trail in {run_dir / AUDIT_DIR}")


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
            f"  remote: {remote['round_trip_ms']:.2f} ms round trip per act (server {remote['server_ms']:.2f} ms, "
            f"worst {remote['max_round_trip_ms']:.1f} ms)"
        )
    return lines
