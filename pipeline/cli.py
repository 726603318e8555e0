"""The `pipeline` command: build, eval, serve, replay, view.

Every subcommand is one function taking the parsed arguments. A ``DyanaError``
becomes a one-line message on stderr and exit code 2; a replay mismatch exits 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from schemas.errors import DyanaError, ReplayMismatch


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a number >= 1, got {text!r}")
    return value


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


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pipeline", description="Build, evaluate, replay and view Dyana episodes.")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("build", help="build a slice's shards (Parquet + MCAP) and its catalog.json")
    p.add_argument("--slice", help="slice name, e.g. linear-fast (see `catalog list`)")
    p.add_argument("--episodes", type=_positive_int, help="build only the first N episodes (of each part for dyana-12m)")
    p.add_argument("--out", default="out", help="output folder; the slice goes to OUT/<slice>/ (default: out)")
    p.add_argument("--workers", type=_positive_int, default=2, help="local worker processes (default: 2)")
    p.add_argument("--scheduler", help="address of an existing Dask scheduler, e.g. tcp://127.0.0.1:8786")
    p.add_argument("--resolution", type=_positive_int, default=224, help="image side in pixels (default: 224)")
    p.add_argument("--shard-size", type=_positive_int, default=128, help="episodes per shard (default: 128)")
    p.add_argument("--specs", help="build the episodes of a JSONL file of EpisodeSpecs instead of the recipe")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_build)

    p = sub.add_parser("view", help="write one episode of a slice or run as a rerun recording (.rrd)")
    p.add_argument("dir", metavar="DIR", help="a built slice or rollout folder (holding catalog.json)")
    p.add_argument("--episode", type=int, default=0, help="episode index (default: 0)")
    p.add_argument("--out", required=True, help="the .rrd file to write")
    p.set_defaults(func=cmd_view)
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
    except KeyboardInterrupt:
        print(f"pipeline {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
