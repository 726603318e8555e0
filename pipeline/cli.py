"""The `pipeline` command: build, eval, serve, replay, view (on :mod:`schemas.cli`)."""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from pipeline import job_flags
from pipeline.policy_registry import config_from_flags, flag_defaults, kind_of, policy_help
from pipeline.remote.wires import PROTOCOLS
from schemas import cli
from schemas.errors import DyanaError
from schemas.names import printable

if TYPE_CHECKING:  # the commands import their modules when run, so --help stays fast
    from catalog.store.records import ShardRecord


def _resumable(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """A folder job's command whose Ctrl-C is one line saying how to resume: the shards it
    finished are kept, and its workers and policy processes end with it."""

    def interruptible(args: argparse.Namespace) -> int:
        try:
            return run(args)
        except KeyboardInterrupt:
            signal.signal(signal.SIGINT, signal.SIG_IGN)  # exiting: a second Ctrl-C adds no traceback
            print(f"pipeline {args.command}: interrupted; rerun the same command to resume", file=sys.stderr)
            return cli.EXIT_INTERRUPTED

    return interruptible


def _build_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--slice", help="slice name, e.g. linear-fast (see `catalog list`)")
    job_flags.add_selection(p, 128, "build only the first N episodes (of each part for dyana-12m)", specs=True)
    job_flags.add_storage(p, "output folder; the slice goes to OUT/<slice>/ (default: out)", default="out")
    job_flags.add_execution(p)
    job_flags.add_settings(p)


def cmd_build(args: argparse.Namespace) -> int:
    if args.slice is None and args.specs is None:
        raise DyanaError("pipeline build needs --slice NAME or --specs FILE.jsonl")
    names = [args.slice]
    if args.specs is None:
        from schemas.slices import get_slice

        definition = get_slice(args.slice)  # a bad name is refused before the build's imports
        if definition.union:
            names = list(definition.parts)
            print(f"{args.slice} is built as its {len(names)} parts: {', '.join(names)}", file=sys.stderr)
    from pipeline.jobs.build import run_build
    for name in names:
        result = run_build(job_flags.job_spec_of(args, name))
        manifest = result.manifest
        verb = "up to date" if result.up_to_date else "built"
        print(
            f"{verb} {manifest.slice}: {manifest.episodes} episodes, {manifest.frames} frames, "
            f"{len(manifest.shards)} shards -> {printable(str(args.out).rstrip('/'), 400)}/{manifest.slice}/catalog.json "
            f"(hash {manifest.hash[:16]})"
        )
    return 0


def _importable_cwd(policy: str) -> None:
    """Let ``module:callable`` refs (a kind that imports a module) name modules in the current
    folder, as ``python -m`` does (Dask's local workers inherit the path)."""
    if kind_of(policy).imports_module and "" not in sys.path and "." not in sys.path:
        sys.path.insert(0, "")


def _eval_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--policy", required=True, help=policy_help())
    p.add_argument("--policy-device", metavar="DEVICE",
                   help="where a lerobot:PATH policy runs: cpu (default), cuda, cuda:N or mps")
    p.add_argument("--slice", default="test-1k", help="slice whose episodes to run (default: test-1k)")
    job_flags.add_selection(p, 32, "only the first N episodes",
                            test_seed="draw the held-out slice (test-1k, test-irregular, test-complex) from this secret "
                            "instead of its public seed; the run's manifest keeps only a hash of it")
    job_flags.add_storage(p, "run folder: RUN/catalog.json and RUN/frames/, RUN/episodes/, RUN/mcap/")
    job_flags.add_execution(p)
    p.add_argument(
        "--deadline", type=cli.positive_float, default=None,
        help="opt-in seconds allowed per policy call, recorded in the manifest (default: none, so load never "
        "decides a result; a 300 s watchdog still fails a call that hangs)",
    )
    p.add_argument(
        "--in-process", action="store_true",
        help="run a module:callable policy inside the eval workers (faster start, but its crash or exit "
        "takes the run down; by default it runs in a child process and fails only its episode)",
    )
    job_flags.add_settings(p, protocol=True)
    vlm = p.add_argument_group("VLM policies (--policy vlm:URL)")
    p.set_defaults(**flag_defaults())  # each policy kind's flags: a set one is refused for another kind
    vlm.add_argument("--model", help="the model name the endpoint serves (required for vlm:URL)")
    vlm.add_argument("--vlm-every", type=cli.positive_int, metavar="K",
                     help="ask the model every K acting frames, moving toward its answer in between (default: 5)")
    vlm.add_argument("--vlm-latency-frames", type=int, metavar="L",
                     help="simulated thinking time: an answer takes effect L frames after its frame (default: 0)")
    vlm.add_argument("--vlm-observe-images", type=int, metavar="N",
                     help="observe-window frames sent with the first query (default: 2)")
    vlm.add_argument("--vlm-on-fault", choices=("error", "hold"),
                     help="an unreadable answer, HTTP error, timeout or refusal fails the episode (error) or "
                     "keeps the hand's current plan (hold) (default: error)")
    vlm.add_argument("--vlm-timeout", type=cli.positive_float, metavar="S",
                     help="seconds to wait for one answer (default: 60)")
    vlm.add_argument("--vlm-template", help="prompt template: a built-in name or a .txt file (default: v1)")
    vlm.add_argument("--vlm-api-key-env", metavar="VAR",
                     help="environment variable holding the API key (default: OPENAI_API_KEY; never a flag)")
    vlm.add_argument("--vlm-no-json-schema", action="store_true",
                     help="do not ask for structured output (for servers that reject response_format)")
    vlm.add_argument("--vlm-temperature", type=float, help="sampling temperature (default: 0)")
    vlm.add_argument("--vlm-seed", type=int, help="sampling seed sent with every request (default: 0)")


def _policy_config(args: argparse.Namespace) -> dict | None:
    """The policy kind's configuration from its flags (a VLM's, a LeRobot checkpoint's device)."""
    return config_from_flags(args.policy, vars(args))


def cmd_eval(args: argparse.Namespace) -> int:
    from schemas.slices import get_slice

    config = _policy_config(args)
    get_slice(args.slice)  # a bad name is refused before the loop's imports
    from pipeline.jobs.evaluate import Report, run_eval
    from pipeline.jobs.repeats import run_repeats
    from pipeline.jobs.spec import PolicyChoice

    _importable_cwd(args.policy)
    policy = PolicyChoice(args.policy, config, not args.in_process, args.deadline, job_flags.protocol_of(args))
    spec = job_flags.job_spec_of(args, args.slice, policy)
    if args.repeats != 1:
        run_repeats(spec, args.repeats, Report(require_success=True))
    else:
        run_eval(spec, Report(require_success=True))
    return 0


def _serve_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--policy", required=True, help=policy_help(servable=True))
    p.add_argument("--policy-device", metavar="DEVICE",
                   help="where a lerobot:PATH policy runs: cpu (default), cuda, cuda:N or mps")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default: 127.0.0.1)")
    p.add_argument("--port", type=cli.port, default=8000, help="port (default: 8000; 0 picks a free one, printed)")
    p.add_argument(
        "--max-message-mb", type=cli.positive_int, default=64,
        help="largest request accepted, in MiB (default: 64: a 94-frame observe window up to 448 px)",
    )
    p.add_argument(
        "--max-connections", type=cli.positive_int, default=4,
        help="connections served at once; more are told the server is busy (default: 4)",
    )
    p.add_argument(
        "--protocol", choices=tuple(PROTOCOLS), default="dyana",
        help="wire protocol: dyana (dyana/1, default) or openpi (for openpi_client; docs/guides/openpi.md)",
    )
    p.add_argument(
        "--openpi-key", action="append", default=[], type=_setting, metavar="NAME=KEY",
        help="with --protocol openpi: a request/reply key name (image, state, prompt, actions); repeatable",
    )


def _setting(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=KEY, got {text[:60]!r}")
    return name, value


def cmd_serve(args: argparse.Namespace) -> int:
    from pipeline.policy_registry import serving_factory
    from pipeline.remote.serve import checked_factory, serve
    from pipeline.remote.wires import wire_for

    wire = wire_for(args.protocol, args.openpi_key)
    _importable_cwd(args.policy)
    factory = checked_factory(serving_factory(args.policy, vars(args)), wire, args.policy)
    serve(
        factory, args.host, args.port,
        max_message_bytes=args.max_message_mb << 20, max_connections=args.max_connections, wire=wire,
        label=args.policy,
    )
    return 0


def _replay_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", metavar="RUN|DIR", help="a run folder or a built slice folder (holding catalog.json)")
    cli.add_quiet(p, "no per-shard lines")
    cli.add_test_seed(p, "the secret a run drawn from a private test seed was made with (needed to replay it)")


def cmd_replay(args: argparse.Namespace) -> int:
    from pipeline.jobs.replay import replay

    def progress(shard: ShardRecord) -> None:
        if not args.quiet:
            print(f"shard {shard.first}-{shard.end - 1}: identical", file=sys.stderr, flush=True)

    report = replay(args.path, on_shard=progress, test_seed=cli.read_test_seed(args))
    what = "rollouts of" if report.kind == "rollouts" else "built slice"
    print(
        f"replayed {what} {report.slice}: {report.episodes} episodes, {report.frames} frames in "
        f"{report.shards} shards: identical"
    )
    return 0


def _view_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", metavar="DIR", help="a built slice or rollout folder (holding catalog.json)")
    p.add_argument("--episode", type=int, default=0, help="episode index (default: 0)")
    p.add_argument("--out", type=cli.output_path, required=True, help="the .rrd file to write")


def cmd_view(args: argparse.Namespace) -> int:
    from pipeline.jobs.view import write_recording

    out = write_recording(args.dir, args.episode, args.out)
    print(f"wrote {out} (open it with: rerun {out})")
    return 0


COMMANDS = (
    cli.Command("build", "build a slice's shards (Parquet + MCAP) and its catalog.json", _build_arguments, _resumable(cmd_build)),
    cli.Command("view", "write one episode of a slice or run as a rerun recording (.rrd)", _view_arguments, cmd_view),
    cli.Command("eval", "run a policy in the loop on a slice's episodes and record the rollouts", _eval_arguments, _resumable(cmd_eval)),
    cli.Command("serve", "serve a policy over WebSocket (dyana/1 or openpi: docs/reference/wire-protocol.md)", _serve_arguments, cmd_serve),
    cli.Command("replay", "re-execute a built slice or a run and check it byte for byte", _replay_arguments, cmd_replay),
)


def main(argv: Sequence[str] | None = None) -> int:
    return cli.run("pipeline", "Build, evaluate, replay and view Dyana episodes.", COMMANDS, argv)


if __name__ == "__main__":
    sys.exit(main())
