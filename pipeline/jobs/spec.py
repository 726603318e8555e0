"""A job request, typed: :class:`JobSpec`, the one value `pipeline build` and `pipeline eval`
(and their Python functions) are given, made of small frozen parts each checked when made
(a :class:`~schemas.errors.SpecError` naming the bad value, before anything is read or written):

- :class:`Selection`: which episodes (a slice, or a specs file; the first ``episodes``;
  a held-out slice's private ``test_seed``) and how many go in a shard;
- the byte settings, :class:`schemas.settings.BuildSettings` (the slice's obstacles and
  a run's protocol are filled in when the job is assembled);
- :class:`~pipeline.jobs.tasks.Execution`: workers, scheduler, progress;
- :class:`Storage`: the output folder or object-store URL, and whether it may be replaced;
- :class:`PolicyChoice`, for an eval: the policy, its configuration and the protocol.

The CLI builds each part from its flag group (:mod:`pipeline.job_flags`); the Python
functions from their keyword options (:func:`job_spec`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from catalog.store.storage import as_location, is_url
from pipeline.jobs.engine import refuse_export_folder
from pipeline.jobs.tasks import Execution
from pipeline.loop.conditions import EvalProtocol
from pipeline.loop.deadlines import check_seconds
from schemas.errors import PolicyError, SpecError
from schemas.formats import ALL_FORMATS, parse_formats
from schemas.names import shorten
from schemas.renderers import DEFAULT_RENDERER, dataset_version_of
from schemas.scene import DEFAULT_RESOLUTION
from schemas.settings import BuildSettings


def _optional_text(name: str, value: object) -> None:
    if value is not None and not isinstance(value, str):
        raise SpecError(f"{name} must be text or None, got {shorten(repr(value))}")


@dataclass(frozen=True)
class Selection:
    """Which episodes a job runs and how they are sharded (module docstring)."""

    slice_name: str | None
    episodes: int | None = None
    shard_size: int = 128
    specs_path: str | None = None
    test_seed: str | None = None
    #: Where ``test_seed`` was read from (hidden from a sealed policy; never recorded).
    test_seed_file: str | None = None

    def __post_init__(self) -> None:
        _optional_text("slice", self.slice_name)
        _optional_text("specs_path", self.specs_path)
        _optional_text("test_seed_file", self.test_seed_file)
        if isinstance(self.shard_size, bool) or not isinstance(self.shard_size, int) or self.shard_size < 1:
            raise SpecError(f"--shard-size must be an integer >= 1, got {shorten(repr(self.shard_size))}")

    def first_episodes(self, available: int, slice_name: str | None = None) -> int:
        """How many episodes the job runs: all ``available``, or the first ``episodes``. For a
        slice (``slice_name``) at most its count; a specs file may be asked for more than it holds."""
        count = available if self.episodes is None else self.episodes
        valid = not isinstance(count, bool) and isinstance(count, int) and count >= 1
        if valid and slice_name is None:
            return min(count, available)
        if valid and count <= available:
            return count
        if slice_name is None:
            raise SpecError(f"--episodes must be >= 1, got {shorten(repr(count))}")
        raise SpecError(f"--episodes must be in [1, {available}] for {slice_name}, got {shorten(repr(count))}")


@dataclass(frozen=True)
class Storage:
    """Where a job's folder is: ``out``, a local folder or an object-store URL; ``overwrite``
    lets it replace another job's folder."""

    out: str | os.PathLike[str]
    overwrite: bool = False

    def __post_init__(self) -> None:
        as_location(self.out, "out")  # a folder name or URL, checked before anything is read
        if not isinstance(self.overwrite, bool):
            raise SpecError(f"overwrite must be True or False, got {shorten(repr(self.overwrite))}")

    @property
    def remote(self) -> bool:
        """Whether ``out`` is an object-store URL."""
        return is_url(self.out)

    @property
    def folder(self) -> Path:
        """The local folder (for a URL, where it would be named locally: messages only)."""
        return Path(self.out)

    def inside(self, name: str) -> Storage:
        """The storage of ``out/name`` (a build writes ``OUT/<slice>``)."""
        out: str | Path = f"{str(self.out).rstrip('/')}/{name}" if self.remote else Path(self.out) / name
        return Storage(out, self.overwrite)

    def refuse_export(self, what: str) -> None:
        """SpecError when the local folder holds a LeRobot export (a folder holds one kind of thing)."""
        if not self.remote:
            refuse_export_folder(self.folder, what)


@dataclass(frozen=True)
class PolicyChoice:
    """An eval's policy: its reference, its kind's configuration (``config``), whether a
    ``module:callable`` runs in a child process (``isolate``), the opt-in per-call deadline
    and the evaluation protocol."""

    ref: str
    config: dict[str, Any] | None = None
    isolate: bool = True
    deadline_s: float | None = None
    protocol: EvalProtocol = field(default_factory=EvalProtocol)

    def __post_init__(self) -> None:
        if self.deadline_s is not None:
            try:
                object.__setattr__(self, "deadline_s", check_seconds("--deadline", self.deadline_s))
            except PolicyError as exc:
                raise SpecError(str(exc)) from None
        if self.protocol is None:
            object.__setattr__(self, "protocol", EvalProtocol())
        if not isinstance(self.protocol, EvalProtocol):
            raise SpecError(f"protocol must be a pipeline.loop.conditions.EvalProtocol or None, got {shorten(repr(self.protocol))}")
        object.__setattr__(self, "isolate", bool(self.isolate))


@dataclass(frozen=True)
class JobSpec:
    """A build's or an eval's request (module docstring); ``policy`` only for an eval."""

    selection: Selection
    settings: BuildSettings
    execution: Execution
    storage: Storage
    policy: PolicyChoice | None = None

    def __post_init__(self) -> None:
        for name, kind in (("selection", Selection), ("settings", BuildSettings), ("execution", Execution),
                           ("storage", Storage)):
            if not isinstance(getattr(self, name), kind):
                raise SpecError(f"{name} must be a {kind.__name__}, got {shorten(repr(getattr(self, name)))}")
        if self.policy is not None and not isinstance(self.policy, PolicyChoice):
            raise SpecError(f"policy must be a PolicyChoice or None, got {shorten(repr(self.policy))}")


def byte_settings(resolution: int = DEFAULT_RESOLUTION, renderer: str = DEFAULT_RENDERER,
                  formats: str | tuple[str, ...] = ALL_FORMATS) -> BuildSettings:
    """The byte settings a user chooses (``--resolution``, ``--renderer``, ``--formats``);
    the rest are derived when the job is assembled."""
    version = dataset_version_of(renderer)
    return BuildSettings(resolution=resolution, formats=parse_formats(formats), dataset_version=version)


#: The keyword options of build() / build_job() / evaluate(), by the part they belong to.
SELECTION_OPTIONS = ("episodes", "shard_size", "specs_path", "test_seed", "test_seed_file")
SETTINGS_OPTIONS = ("resolution", "renderer", "formats")
EXECUTION_OPTIONS = ("workers", "scheduler", "progress")
POLICY_OPTIONS = ("config", "isolate", "deadline_s", "protocol")


def job_spec(slice_name: str | None, out: str | os.PathLike[str], options: Mapping[str, Any], *,
             shard_size: int, policy_ref: str | None = None) -> JobSpec:
    """The :class:`JobSpec` of a Python call's keyword ``options`` (the CLI flags' names,
    ``specs_path`` for ``--specs``); TypeError for an option the call does not take, as Python's own."""
    known = {*SELECTION_OPTIONS, *SETTINGS_OPTIONS, *EXECUTION_OPTIONS, "overwrite"}
    if policy_ref is not None:
        known |= set(POLICY_OPTIONS)
    unknown = sorted(set(options) - known)
    if unknown:
        raise TypeError(f"got an unexpected keyword argument {unknown[0]!r}")
    settings = byte_settings(**{k: options[k] for k in SETTINGS_OPTIONS if k in options})
    storage = Storage(out, options.get("overwrite", False))
    selection = Selection(slice_name, **{"shard_size": shard_size, **{k: options[k] for k in SELECTION_OPTIONS
                                                                        if k in options}})
    execution = Execution.of(**{k: options[k] for k in EXECUTION_OPTIONS if k in options})
    policy = None
    if policy_ref is not None:
        policy = PolicyChoice(policy_ref, **{k: options[k] for k in POLICY_OPTIONS if k in options})
    return JobSpec(selection, settings, execution, storage, policy)


__all__ = ["JobSpec", "PolicyChoice", "Selection", "Storage", "byte_settings", "job_spec"]
