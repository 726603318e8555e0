"""The `pipeline` command: build, eval, serve, replay, view.

Every subcommand is one function taking the parsed arguments. A ``DyanaError``
becomes a one-line message on stderr and exit code 2; a replay mismatch exits 1.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from pipeline.cli_args import OneLineParser, positive_int
from schemas.errors import DyanaError, ReplayMismatch


def cmd_build(args: argparse.Namespace) -> int:
    from pipeline.build import build

    if args.slice is None and args.specs is None:
        raise DyanaError("pipeline build needs --slice NAME or --specs FILE.jsonl")
    names = [args.slice]
    if args.specs is None:
        from schemas.slices import get_slice

        definition = get_slice(args.slice)
        if definition.union:
            names = list(definition.parts)
            print(f"{args.slice} is built as its {len(names)} parts: {', '.join(names)}", file=sys.stderr)
    for name in names:
        manifest = build(
            name,
            Path(args.out),
            episodes=args.episodes,
            workers=args.workers,
            scheduler=args.scheduler,
            resolution=args.resolution,
            shard_size=args.shard_size,
            specs_path=args.specs,
            progress=not args.quiet,
        )
        print(
            f"built {manifest.slice}: {manifest.episodes} episodes, {manifest.frames} frames, "
            f"{len(manifest.shards)} shards -> {Path(args.out) / manifest.slice / 'catalog.json'} "
            f"(hash {manifest.hash[:16]})"
        )
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from pipeline.view import write_recording

    out = write_recording(args.dir, args.episode, args.out)
    print(f"wrote {out} (open it with: rerun {out})")
    return 0


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port in [0, 65535] (0 = any free port), got {text!r}")
    return value


def _importable_cwd(policy: str) -> None:
    """Let ``module:callable`` refs name modules in the current folder, as ``python -m`` does
    (Dask's local workers inherit the path)."""
    if ":" in policy and not policy.startswith(("ws://", "wss://")) and "" not in sys.path and "." not in sys.path:
        sys.path.insert(0, "")


def cmd_eval(args: argparse.Namespace) -> int:
    from pipeline.evaluate import evaluate

    _importable_cwd(args.policy)
    evaluate(
        args.policy,
        args.slice,
        Path(args.out),
        episodes=args.episodes,
        workers=args.workers,
        scheduler=args.scheduler,
        deadline_s=args.deadline,
        resolution=args.resolution,
        shard_size=args.shard_size,
        progress=not args.quiet,
    )
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    from pipeline.serve import serve

    _importable_cwd(args.policy)
    serve(args.policy, args.host, args.port)
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from pipeline.replay import replay

    def progress(shard) -> None:
        if not args.quiet:
            print(f"shard {shard.first}-{shard.end - 1}: identical", file=sys.stderr, flush=True)

    report = replay(args.path, on_shard=progress)
    what = "rollouts of" if report.kind == "rollouts" else "built slice"
    print(
        f"replayed {what} {report.slice}: {report.episodes} episodes, {report.frames} frames in "
        f"{report.shards} shards: identical"
    )
    return 0


def make_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="pipeline", description="Build, evaluate, replay and view Dyana episodes.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)

    p = sub.add_parser("build", help="build a slice's shards (Parquet + MCAP) and its catalog.json")
    p.add_argument("--slice", help="slice name, e.g. linear-fast (see `catalog list`)")
    p.add_argument("--episodes", type=positive_int, help="build only the first N episodes (of each part for dyana-12m)")
    p.add_argument("--out", default="out", help="output folder; the slice goes to OUT/<slice>/ (default: out)")
    p.add_argument("--workers", type=positive_int, default=os.cpu_count() or 1,
                   help=f"local single-threaded worker processes (default: one per core, {os.cpu_count() or 1} here)")
    p.add_argument("--scheduler", help="address of an existing Dask scheduler, e.g. tcp://127.0.0.1:8786")
    p.add_argument("--resolution", type=positive_int, default=224, help="image side in pixels (default: 224)")
    p.add_argument("--shard-size", type=positive_int, default=128, help="episodes per shard (default: 128)")
    p.add_argument("--specs", help="build the episodes of a JSONL file of EpisodeSpecs instead of the recipe")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_build)

    p = sub.add_parser("view", help="write one episode of a slice or run as a rerun recording (.rrd)")
    p.add_argument("dir", metavar="DIR", help="a built slice or rollout folder (holding catalog.json)")
    p.add_argument("--episode", type=int, default=0, help="episode index (default: 0)")
    p.add_argument("--out", required=True, help="the .rrd file to write")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("eval", help="run a policy in the loop on a slice's episodes and record the rollouts")
    p.add_argument("--policy", required=True, help="oracle, still, chase, predictive, module:callable or ws://HOST:PORT")
    p.add_argument("--slice", default="test-1k", help="slice whose episodes to run (default: test-1k)")
    p.add_argument("--episodes", type=positive_int, help="only the first N episodes")
    p.add_argument("--out", required=True, help="run folder: RUN/catalog.json and RUN/shards/")
    p.add_argument("--workers", type=positive_int, default=os.cpu_count() or 1,
                   help=f"local single-threaded worker processes (default: one per core, {os.cpu_count() or 1} here)")
    p.add_argument("--scheduler", help="address of an existing Dask scheduler, e.g. tcp://127.0.0.1:8786")
    p.add_argument("--deadline", type=_positive_float, default=10.0, help="seconds allowed per policy call (default: 10)")
    p.add_argument("--resolution", type=positive_int, default=224, help="image side in pixels (default: 224)")
    p.add_argument("--shard-size", type=positive_int, default=32, help="episodes per shard (default: 32)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("serve", help="serve a policy over WebSocket (protocol dyana/1, see the README)")
    p.add_argument("--policy", required=True, help="oracle, still, chase, predictive or module:callable")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default: 127.0.0.1)")
    p.add_argument("--port", type=_port, default=8000, help="port (default: 8000; 0 picks a free one, printed)")
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("replay", help="re-execute a built slice or a run and check it byte for byte")
    p.add_argument("path", metavar="RUN|DIR", help="a run folder or a built slice folder (holding catalog.json)")
    p.add_argument("--quiet", action="store_true", help="no per-shard lines")
    p.set_defaults(func=cmd_replay)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = make_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ReplayMismatch as exc:
        print(f"pipeline {args.command}: {exc}", file=sys.stderr)
        return 1
    except DyanaError as exc:
        print(f"pipeline {args.command}: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # an output folder that cannot be created or written, a full disk, ...
        print(f"pipeline {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"pipeline {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
