"""The flag groups of the sharded jobs' commands (`pipeline build`, `pipeline eval`): for each
part of a :class:`~pipeline.jobs.spec.JobSpec`, one function adds its flags to a command
and one turns the parsed flags into the part, so both commands check and assemble them
the same way. The byte settings' flags are those :class:`schemas.settings.BuildSettings`'
field metadata names, each registered here (:data:`SETTING_FLAGS`)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TYPE_CHECKING

from schemas import cli
from schemas.settings import BuildSettings, setting_flags

if TYPE_CHECKING:  # the commands import their modules when run, so --help stays fast
    from pipeline.jobs.spec import JobSpec, PolicyChoice, Selection, Storage
    from pipeline.jobs.tasks import Execution
    from pipeline.loop.conditions import EvalProtocol


# --- selection -------------------------------------------------------------------------


def add_selection(p: argparse.ArgumentParser, shard_size: int, episodes: str, *, specs: bool = False,
                  test_seed: str | None = None) -> None:
    """``--episodes``, ``--shard-size``; a build's ``--specs``; an eval's ``--test-seed``."""
    cli.add_episodes(p, episodes)
    cli.add_shard_size(p, shard_size)
    if specs:
        p.add_argument("--specs", help="build the episodes of a JSONL file of EpisodeSpecs instead of the recipe")
    if test_seed is not None:
        cli.add_test_seed(p, test_seed)


def selection_of(args: argparse.Namespace, slice_name: str | None) -> Selection:
    from pipeline.jobs.spec import Selection

    return Selection(slice_name, args.episodes, args.shard_size, getattr(args, "specs", None), cli.read_test_seed(args),
                     getattr(args, "test_seed_file", None))


# --- byte settings -----------------------------------------------------------------------


def add_protocol(p: argparse.ArgumentParser) -> None:
    """An eval's protocol flags (recorded in ``settings.protocol``)."""
    protocol = p.add_argument_group("protocols (recorded in the run's manifest, settings.protocol)")
    protocol.add_argument("--latency-frames", type=int, default=0, metavar="N",
                          help="an action computed from frame t's observation takes effect at frame t + N; "
                          "the hand holds meanwhile (default: 0; deterministic)")
    protocol.add_argument("--realtime", action="store_true",
                          help="also delay each call's actions by its measured inference time in whole frames "
                          "(NOT deterministic: flagged in the manifest and every table; cannot be replayed)")
    protocol.add_argument("--perturb", metavar="NAME[:STRENGTH]",
                          help="perturb what the policy sees: noise[:2], jpeg[:75], jitter[:0.5] or light[:2] "
                          "(seeded by the episode, the repeat and the frame)")
    protocol.add_argument("--disturb", action="store_true",
                          help="change each episode's motion once after the observe window (seeded by the episode: "
                          "a speed or heading change); the run records the disturbed specs")
    protocol.add_argument("--repeats", type=int, default=1, metavar="K",
                          help="run every episode K times (repeat r seeds its own perturbation): RUN/repeat-NN "
                          "plus RUN/repeats.json, scored together by scoring eval RUN (default: 1)")


#: Byte-setting flag -> the function that registers it (one may register several: the protocol's).
SETTING_FLAGS: dict[str, Callable[[argparse.ArgumentParser], None]] = {
    "--resolution": cli.add_resolution,
    "--renderer": cli.add_renderer,
    "--formats": cli.add_formats,
    **dict.fromkeys(("--latency-frames", "--realtime", "--perturb", "--disturb", "--repeats"), add_protocol),
}


def add_settings(p: argparse.ArgumentParser, *, protocol: bool = False) -> None:
    """The flags of the byte settings (:func:`schemas.settings.setting_flags`), in field
    order; the protocol's only for an eval (``protocol``)."""
    added: list[Callable[[argparse.ArgumentParser], None]] = []
    for flag, name in setting_flags().items():
        register = SETTING_FLAGS[flag]
        if register in added or (name == "protocol" and not protocol):
            continue
        register(p)
        added.append(register)


def settings_of(args: argparse.Namespace) -> BuildSettings:
    """The byte settings the flags choose (a run's protocol is :func:`protocol_of`'s)."""
    from pipeline.jobs.spec import byte_settings

    chosen = [flag for flag, name in setting_flags().items() if name != "protocol"]
    return byte_settings(**{flag[2:].replace("-", "_"): getattr(args, flag[2:].replace("-", "_")) for flag in chosen})


def protocol_of(args: argparse.Namespace) -> EvalProtocol:
    from pipeline.loop.conditions import EvalProtocol
    from pipeline.loop.perturb import Perturbation

    perturb = None if args.perturb is None else Perturbation.parse(args.perturb)
    return EvalProtocol(latency_frames=args.latency_frames, realtime=args.realtime, perturb=perturb,
                        disturb=args.disturb)


# --- execution and storage ---------------------------------------------------------------


def add_execution(p: argparse.ArgumentParser) -> None:
    """``--workers``, ``--scheduler``, ``--quiet``."""
    cli.add_workers(p)
    cli.add_quiet(p)


def execution_of(args: argparse.Namespace) -> Execution:
    from pipeline.jobs.tasks import Execution

    return Execution.of(args.workers, args.scheduler, not args.quiet)


def add_storage(p: argparse.ArgumentParser, what: str, *, default: str | None = None) -> None:
    """``--out`` (required unless it has a ``default``) and ``--overwrite``."""
    p.add_argument("--out", type=cli.output_path, default=default, required=default is None, help=what)
    cli.add_overwrite(p)


def storage_of(args: argparse.Namespace) -> Storage:
    from pipeline.jobs.spec import Storage

    return Storage(args.out, args.overwrite)


def job_spec_of(args: argparse.Namespace, slice_name: str | None, policy: PolicyChoice | None = None) -> JobSpec:
    """The command's :class:`~pipeline.jobs.spec.JobSpec`, from its flag groups."""
    from pipeline.jobs.spec import JobSpec

    return JobSpec(selection_of(args, slice_name), settings_of(args), execution_of(args), storage_of(args), policy)
