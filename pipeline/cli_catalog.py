"""The ``catalog`` command: the slice registry and the recipe seen from the shell.

``catalog list`` lists the slices with their episode and frame counts;
``catalog export DIR [DIR ...] --format lerobot|lerobot-v2.1 --out OUT`` writes a LeRobot dataset;
``catalog stats SLICE [--json]`` enumerates a slice's recipe (Figure 4's numbers for
``dyana-12m``); ``catalog specs SLICE [--episodes N]`` prints its specs as JSONL, to
inspect, edit and build with ``pipeline build --specs``; ``catalog info DIR|URL [--json]``
says which code and dataset version wrote a folder, what it holds, and whether this code
rebuilds it byte for byte.

It lives in ``pipeline`` because it needs the recipe (``generators``), which the
``catalog`` package may not import. Each subcommand is a :class:`schemas.cli.Command`;
errors print one line and exit with code 2 (see :mod:`schemas.cli`).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from schemas import cli
from schemas.errors import SpecError
from schemas.slices import get_slice
from schemas.versions import DATASET_VERSION, FPS

if TYPE_CHECKING:  # imported by the commands when run
    from catalog.store.records import ShardRecord


def _print_json(data: object) -> None:
    print(json.dumps(data, sort_keys=False))


def _size(n: int) -> str:
    """Bytes as a short decimal size: 845 MB, 12.3 GB."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            value = n / scale
            return f"{value:.1f} {unit}" if value < 100 else f"{value:.0f} {unit}"
    return f"{n} B"


def cmd_list(args: argparse.Namespace) -> int:
    from catalog.store.footprint import expected_footprint
    from generators.recipe import slice_overview

    rows = slice_overview()
    by_name = {row["slice"]: row for row in rows}
    for row in rows:
        definition = get_slice(row["slice"])
        parts = definition.parts if definition.union else (row["slice"],)
        size = expected_footprint({p: (by_name[p]["episodes"], by_name[p]["frames"]) for p in parts})
        row["expected_bytes"] = None if size is None else {"parquet": size.parquet, "mcap": size.mcap,
                                                           "total": size.total}
    if args.json:
        _print_json(rows)
        return 0
    print(f"{'slice':<17} {'motion':<10} {'setting':<8} {'episodes':>9} {'frames':>11} {'seed':>5} "
          f"{'parquet':>9} {'+ mcap':>9}")
    for row in rows:
        definition = get_slice(row["slice"])
        motion = row["motion_type"] or ("all" if definition.union else "mixed")
        setting = row["intercept_setting"] or ("all" if definition.union else "mixed")
        seed = "parts" if definition.union else str(row["seed"])
        size = row["expected_bytes"]
        parquet, total = ("-", "-") if size is None else (_size(size["parquet"]), _size(size["total"]))
        print(f"{row['slice']:<17} {motion:<10} {setting:<8} {row['episodes']:>9,} {row['frames']:>11,} {seed:>5} "
              f"{parquet:>9} {total:>9}")
    print("sizes: expected on disk at 224 px (catalog/store/footprint.json, measured by benchmarks/footprint.py); "
          "'+ mcap' is the default --formats parquet,mcap")
    return 0


def _list_arguments(p: argparse.ArgumentParser) -> None:
    cli.add_json(p, "print a JSON list instead of a table")


def cmd_stats(args: argparse.Namespace) -> int:
    from generators.recipe import slice_summary

    stats = slice_summary(args.slice, args.episodes)
    if args.json:
        _print_json(stats)
        return 0
    hours = stats["total_frames"] / FPS / 3600.0
    print(
        f"slice {stats['slice']}: {stats['total_episodes']:,} episodes, "
        f"{stats['total_frames']:,} frames ({hours:.1f} h at {FPS} FPS)"
    )
    print(f"objects: {stats['objects']['categories']} categories, {stats['objects']['rolling']} rolling")
    formats = ", ".join(f"{name} {count:,}" for name, count in stats["rollout_formats"].items())
    print(f"rollout formats: {formats}")
    print(f"{'motion':<10} {'episodes':>9} {'parameter sets':>15} {'mean frames':>12}")
    for name, row in stats["motion_types"].items():
        mean = "-" if row["mean_frames"] is None else f"{row['mean_frames']:.2f}"
        print(f"{name:<10} {row['episodes']:>9,} {row['parameter_sets']:>15,} {mean:>12}")
    return 0


def _stats_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("slice", metavar="SLICE", help="slice name (see `catalog list`)")
    cli.add_episodes(p)
    cli.add_json(p, "print one JSON object")


def cmd_specs(args: argparse.Namespace) -> int:
    from generators.recipe import slice_specs

    specs = slice_specs(args.slice, args.episodes)
    write = sys.stdout.write
    for spec in specs:
        write(spec.to_json() + "\n")
    sys.stdout.flush()
    return 0


def _specs_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("slice", metavar="SLICE", help="slice name (see `catalog list`)")
    cli.add_episodes(p)


def _seed_text(location: str, seed: int | None) -> str:
    """A folder's seed as ``catalog info`` shows it: a private test seed by its hash only."""
    from catalog.store.manifest import MANIFEST_NAME, load_manifest
    from catalog.store.storage import as_location
    from generators.heldout import MANIFEST_KEY

    if seed is not None:
        return str(seed)
    root = as_location(location)
    record = load_manifest(root.parent if root.name == MANIFEST_NAME else root).extra.get(MANIFEST_KEY)
    if isinstance(record, dict):
        return f"private (scrypt hash {str(record.get('hash'))[:12]}...; replaying it needs --test-seed)"
    return "none (specs file)"


def cmd_verify(args: argparse.Namespace) -> int:
    from pipeline.jobs.verify import verify

    def progress(shard: ShardRecord) -> None:
        print(f"rebuilt shard episodes [{shard.first}, {shard.end}): identical", file=sys.stderr, flush=True)

    report = verify(args.dir, sample=args.sample, on_shard=None if args.quiet else progress,
                    test_seed=cli.read_test_seed(args))
    print(
        f"{args.dir}: OK: {report.shards_checked} shards intact, "
        f"{report.shards_rebuilt} rebuilt byte for byte"
    )
    return 0


def _verify_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", metavar="DIR", help="a built slice or rollout folder (holding catalog.json)")
    p.add_argument("--sample", type=cli.positive_int, default=None, metavar="K", help="rebuild only K shards (default: all)")
    cli.add_quiet(p)
    cli.add_test_seed(p, "the secret a run drawn from a private test seed was made with (needed to re-execute it)")


def cmd_migrate(args: argparse.Namespace) -> int:
    from pipeline.jobs.migrate import migrate

    for report in migrate(args.dir):
        if report.already:
            print(f"{report.folder}: already migrated ({report.shards} shards in frames/, episodes/, mcap/; "
                  "catalog.json sealed)")
        elif report.moved:
            sealed = "; every file checked, catalog.json sealed" if report.sealed else ""
            print(f"{report.folder}: moved {report.moved} files of {report.shards} shards into frames/, episodes/, "
                  f"mcap/ (files and hash unchanged{sealed})")
        else:
            print(f"{report.folder}: every file checked, catalog.json sealed ({report.shards} shards, hash unchanged)")
    return 0


def _migrate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", metavar="DIR", help="a slice or run folder of a previous release, or a run of repeats")


def cmd_export(args: argparse.Namespace) -> int:
    from catalog.export.lerobot import ExportSettings
    from pipeline.jobs.export import export
    from pipeline.jobs.progress import to_stderr

    settings = ExportSettings(args.format, args.codec, args.environment_state)
    workers = args.workers or cli.default_worker_count()
    report = export(args.dirs, args.out, settings, workers=workers, overwrite=args.overwrite,
                    progress=None if args.quiet else to_stderr)
    if report.up_to_date:
        print(f"{report.out}: up to date ({settings.format}, {report.episodes} episodes, {report.frames} frames)")
        return 0
    resumed = f", {report.units_resumed} shards resumed" if report.units_resumed else ""
    rate = report.frames / report.seconds if report.seconds > 0 else 0.0
    print(
        f"exported {' '.join(args.dirs)} as {settings.format} ({settings.version}, {settings.codec}): {report.episodes} episodes, "
        f"{report.frames} frames in {report.seconds:.1f} s ({rate:.0f} frames/s{resumed}) -> {report.out}"
    )
    return 0


def _export_arguments(p: argparse.ArgumentParser) -> None:
    from catalog.export.layout import FORMATS
    from catalog.export.video import CODECS
    from catalog.loader.lerobot_names import ENV_KEY

    p.add_argument("dirs", metavar="DIR", nargs="+", help="built slice or evaluated run folders (holding "
                   "catalog.json); several become one dataset, episodes renumbered in the order given")
    p.add_argument("--environment-state", action="store_true",
                   help=f"also export the object's true pose as {ENV_KEY} (privileged: LeRobot "
                   "policies take every observation.* feature, and the closed loop never gives this one)")
    p.add_argument("--format", choices=sorted(FORMATS), default="lerobot",
                   help="lerobot: LeRobot v3.0; lerobot-v2.1: LeRobot v2.1 with GR00T's meta/modality.json")
    p.add_argument("--out", type=cli.output_path, required=True, metavar="OUT", help="the export's folder (one export per folder)")
    p.add_argument("--codec", choices=sorted(CODECS), default="h264", help="video codec (default: h264)")
    p.add_argument("--workers", type=cli.positive_int, default=None, help="processes encoding shards in parallel "
                   f"(default: one per core{cli.cores_here()})")
    cli.add_overwrite(p)
    cli.add_quiet(p)


def _setting(value: object) -> str:
    """A setting's value on one line: lists joined by commas, objects as compact JSON."""
    if isinstance(value, (list, tuple)):
        return ",".join(str(v) for v in value)
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True, separators=(",", ":"))
    if value is None or isinstance(value, bool):
        return json.dumps(value)
    return str(value)


def cmd_info(args: argparse.Namespace) -> int:
    # lazy, as the other commands: the job modules load numpy, pyarrow and the env
    from catalog.store.info import folder_info, shown_settings
    from catalog.store.repeat_sets import repeats_hint

    hint = repeats_hint(args.dir)  # as every reader of one run says it (catalog.store.manifest.load_manifest)
    if hint:
        raise SpecError(hint)
    info = folder_info(args.dir)
    if args.json:
        _print_json(info.to_dict())
        return 0
    kind = f"rollouts of policy {info.policy}" if info.kind == "rollouts" else "built slice (ground truth)"
    settings = " ".join(f"{k}={_setting(v)}" for k, v in sorted(shown_settings(info.settings).items()) if k != "dataset_version")
    rows = [
        ("folder", info.path),
        ("kind", kind),
        ("dataset", f"{info.dataset_version} (this code writes {DATASET_VERSION})"),
        ("code", f"{info.code_version}, commit {info.commit or 'unknown (not written from a git checkout)'}"),
        ("slice", f"{info.slice}, seed {_seed_text(args.dir, info.seed)}"),
        ("settings", settings),
        ("episodes", f"{info.episodes:,} in {info.shards:,} shard{'s' if info.shards != 1 else ''}"),
        ("frames", f"{info.frames:,}"),
        ("size", f"{_size(info.size)} in {info.files} files"),
        ("hash", info.hash[:16]),
        ("versions", "not recorded (written before Dyana recorded them)" if info.versions is None else
         " ".join(f"{k}={v or '(none)'}" for k, v in sorted(info.versions.items()))),
        ("rebuild", f"{'yes' if info.rebuild.possible else 'no'}: {info.rebuild.reason}"),
    ]
    for name, value in rows:
        print(f"{name:<9} {value}")
    return 0


def _info_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", metavar="DIR|URL", help="a built slice or run folder (holding catalog.json), or its URL")
    cli.add_json(p, "print one JSON object")


COMMANDS = (
    cli.Command("list", "list the slices with their episode and frame counts", _list_arguments, cmd_list),
    cli.Command("stats", "enumerate a slice's recipe and print its statistics", _stats_arguments, cmd_stats),
    cli.Command(
        "specs", "print a slice's episode specs as JSONL (edit, then `pipeline build --specs`)", _specs_arguments, cmd_specs
    ),
    cli.Command("verify", "check every file's sha256 and rebuild shards to compare bytes", _verify_arguments, cmd_verify),
    cli.Command("migrate", "bring a previous release's folder up to date: check it, seal catalog.json, move a 2.0.0 "
                "folder's shards/ into frames/, episodes/, mcap/", _migrate_arguments,
                cmd_migrate),
    cli.Command("export", "export a slice or run as a LeRobot dataset (v3.0, or v2.1 for GR00T)", _export_arguments,
                cmd_export),
    cli.Command("info", "what a folder holds, which code and dataset version wrote it, and whether this code "
                "rebuilds it byte for byte", _info_arguments, cmd_info),
)


def main(argv: Sequence[str] | None = None) -> int:
    return cli.run("catalog", "Dyana slices: list, statistics, episode specs and verification.", COMMANDS, argv)


if __name__ == "__main__":
    sys.exit(main())
