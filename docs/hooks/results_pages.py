"""The results and benchmark pages, generated from the files in ``benchmarks/results/``.

No figure on these pages is typed by hand: each section shows one result file as its
script wrote it, names the script that writes it, and gives the load average the file
records (or says that it records none). Rerun the script, rebuild the site, and the page
follows.
"""

from __future__ import annotations

import ast
import json
import re
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

RESULTS = Path("benchmarks") / "results"
#: Where the raw result files are published inside the site (linked from the pages).
FILES_URI = "results/files"
#: Not published: Markdown would become a page of its own, a checkpoint is no reading.
UNPUBLISHED = (".md", ".pt")


@dataclass(frozen=True)
class Source:
    """One result file: its name under benchmarks/results/, the script that writes it, a title."""

    name: str
    script: str
    title: str
    #: For a figure: the JSON file beside it that records its commit, dataset version and load.
    record: str | None = None


TEST_1K = (
    Source("table.md", "closed_loop_results.py", "Scores"),
    Source("radar.png", "closed_loop_results.py", "Radar and per-motion success rates", "record.json"),
    Source("record.json", "closed_loop_results.py", "Where the scores come from: commits, dataset version, load"),
    Source("latency.png", "latency.py", "S_loc and E_loc against latency", "latency.json"),
    Source("latency.json", "latency.py", "Where the latency figure comes from"),
)
TEST_COMPLEX = (
    Source("test_complex_table.md", "closed_loop_results.py", "Scores"),
    Source("test_complex_radar.png", "closed_loop_results.py", "Radar and success by scene", "test_complex_record.json"),
    Source("test_complex_record.json", "closed_loop_results.py", "Where the scores come from: commits, dataset version, load"),
    Source("projectile_strip.png", "frame_strip.py", "projectile-medium episode 1", "projectile_strip.json"),
    Source("obstacle_strip.png", "frame_strip.py", "obstacle-medium episode 2", "obstacle_strip.json"),
    Source("irregular_strip.png", "frame_strip.py", "irregular-medium episode 4", "irregular_strip.json"),
)
BASELINE = Source("chunk_cnn/config.json", "train_chunk_cnn.py", "Training record of chunk_cnn")
LEROBOT = Source("lerobot_act/record.json", "lerobot_act.py", "Training record of the LeRobot ACT")
TIMINGS = (
    Source("first_screen.json", "first_screen.py", "The first screen: command 1 and the tests"),
    Source("speed_targets.txt", "speed_targets.py", "Speed targets"),
    Source("closed_loop_speed.txt", "closed_loop_speed.py", "Closed-loop speed"),
    Source("build_profile.json", "build.py", "Build profile: CPU per frame by stage"),
    Source("closed_loop_profile.txt", "closed_loop_speed.py", "Closed loop against build, by stage"),
    Source("window_render.txt", "window_render.py", "Window rendering: the full-viewport draw against the window (dataset 4.0.0)"),
    Source("visibility.txt", "visibility.py", "Visibility of the object"),
    Source("dataloader.txt", "dataloader.py", "Loader against bare decoding"),
)
SCALING = Source("scaling.json", "scaling.py", "Scaling and a projection of dyana-12m")


def json_records(text: str) -> list[dict]:
    """Every line of ``text`` that is a JSON object (the scripts print their record last)."""
    out = []
    for line in text.splitlines():
        if line.startswith("{"):
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(record, dict):
                out.append(record)
    return out


def load_values(record: object, path: str = "") -> Iterator[tuple[str, object]]:
    if isinstance(record, dict):
        for key, value in record.items():
            where = f"{path}.{key}" if path else key
            if "load" in key.lower() and not isinstance(value, dict):
                yield where, value
            else:
                yield from load_values(value, where)


def load_note(text: str) -> str:
    """The load averages a result file records, as one sentence."""
    found = [f"`{key}` {value}" for record in json_records(text) for key, value in load_values(record)]
    if not found:
        return "This file records no load average: its times were taken on a shared machine at an unknown load."
    return "Load average (1, 5, 15 min) recorded in the file, one per run in file order: " + "; ".join(found) + "."


def _script_link(script: str) -> str:
    return f"`python benchmarks/{script}`" if script.endswith(".py") else f"`{script}`"


def last_change(root: Path, relative: Path) -> str:
    """``, last changed in commit abc1234 (DATE)`` from git, or nothing outside a git checkout."""
    try:
        found = subprocess.run(["git", "log", "-1", "--format=%h %ad", "--date=short", "--", str(relative)],
                               cwd=root, capture_output=True, text=True, timeout=30).stdout.split()
    except (OSError, subprocess.SubprocessError):
        return ""
    return f", last changed in commit {found[0]} ({found[1]})" if len(found) == 2 else ""


def _source_line(root: Path, source: Source, files: str) -> str:
    name = f"`benchmarks/results/{source.name}`"
    shown = name if Path(source.name).suffix in UNPUBLISHED else f"[{name}]({files}/{source.name})"
    return f"Source: {shown}, written by {_script_link(source.script)}{last_change(root, RESULTS / source.name)}."


def _demote(markdown: str) -> str:
    """Headings one level down, so a results file's ``##`` sits under the page's sections."""
    return re.sub(r"^(#+) ", lambda m: "#" * min(len(m.group(1)) + 1, 6) + " ", markdown, flags=re.M)


def _section(root: Path, source: Source, files: str) -> list[str]:
    """One result file's section; ``files`` is the published files' folder relative to the page."""
    path = root / RESULTS / source.name
    lines = [f"## {source.title}", ""]
    if not path.exists():
        return lines + [f"Not measured yet: run {_script_link(source.script)} to write "
                        f"`benchmarks/results/{source.name}`.", ""]
    lines += [_source_line(root, source, files), ""]
    if path.suffix == ".png":
        return lines + [figurerecord_provenance(root, source), "", f"![{source.title}]({files}/{source.name})", ""]
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".md":  # its first heading is this section's
        return lines + [_demote(re.sub(r"\A## [^\n]*\n", "", text.lstrip())).strip(), ""]
    if path.suffix == ".json":
        return lines + _json_section(text)
    shown = "\n".join(line for line in text.rstrip().splitlines() if not line.startswith("{"))
    records = len(json_records(text))
    also = f" Its {records} JSON record(s), every figure at full precision, are in the file." if records else ""
    return lines + [load_note(text) + also, "", "```text", shown, "```", ""]


def record_provenance(record: object) -> dict | None:
    """The first object in a result record that names a commit and a dataset version."""
    if isinstance(record, dict):
        if "commit" in record and "dataset_version" in record:
            return record
        for value in record.values():
            found = record_provenance(value)
            if found is not None:
                return found
    return None


def figurerecord_provenance(root: Path, source: Source) -> str:
    """One sentence on where a figure comes from: its record's commit, dataset version and load."""
    path = None if source.record is None else root / RESULTS / source.record
    if path is None or not path.exists():
        return "No record of this figure's commit, dataset version or load is kept beside it."
    record = json.loads(path.read_text(encoding="utf-8"))
    found = record_provenance(record) or {}
    loads = [f"{value}" for _, value in load_values(record)]
    return (f"Made at commit {str(found.get('commit'))[:7]}, dataset {found.get('dataset_version')} "
            f"(`benchmarks/results/{source.record}`; load average {'; '.join(loads) or 'not recorded'}).")


def _json_section(text: str) -> list[str]:
    record = json.loads(text)
    # values as code: "<data>/linear-fast" would otherwise lose "<data>" to the HTML parser
    rows = [f"| `{key}` | `{json.dumps(value)}` |" for key, value in _flatten(record)]
    return [load_note(json.dumps(record)), "", "| field | value |", "|---|---|", *rows, ""]


def _flatten(record: object, path: str = "") -> Iterator[tuple[str, object]]:
    if isinstance(record, dict):
        for key, value in record.items():
            yield from _flatten(value, f"{path}.{key}" if path else key)
    else:
        yield path, record


def provenance_note(root: Path, name: str) -> str:
    """One sentence on what the runs behind a scores file were made with, from its record
    (``closed_loop_results.py``'s ``record.json``): dataset versions, commits, resolutions."""
    path = root / RESULTS / name
    if not path.exists():
        return f"`benchmarks/results/{name}` is not written yet: the runs' provenance is unknown."
    record = json.loads(path.read_text(encoding="utf-8"))
    runs = record["runs"].values()
    versions = ", ".join(sorted({str(r["dataset_version"]) for r in runs}))
    commits = ", ".join(sorted({str(r["commit"])[:7] for r in runs}))
    pixels = ", ".join(f"{p} px" for p in sorted({int(r["resolution"]) for r in runs}))
    scored = record["scored"]
    return (f"Every run behind these scores holds dataset {versions} frames ({pixels}), made at commit(s) {commits}; "
            f"the table was scored at commit {str(scored['commit'])[:7]} on {scored['date_utc']} UTC "
            f"(`{name}`, below, has each run's hash, wall time and load).")


#: Only test-1k has the LeRobot row.
LEROBOT_NOTE = (
    "The LeRobot ACT row (`lerobot-act-...`) was trained by `benchmarks/lerobot_act.py` with LeRobot's own "
    "`lerobot-train` and run in LeRobot's environment at 96 px (its training record below), on the same episodes; "
    "`closed_loop_results.py --add-run` scored it with the others."
)
#: Why 450 of test-1k's 1,000 episodes, and what the chance row is.
EPISODES_NOTE = (
    "The scores use test-1k's first 450 episodes: 50 in each of its 9 motion x interception cells "
    "(episode i is in cell i mod 9), so every cell weighs the same, and every row is run on those same 450 "
    "(`closed_loop_results.py --episodes 450`). The one chance row is, per metric, the best of the four blind "
    "policies (`blind-centre`, `blind-sweep`, `blind-first-seen`, `blind-fitted`) on those 450 episodes. The "
    "radar draws families, not runs: each family is a band from its worst to its best member, with a line at "
    "the best; the table has every run."
)


def test_1k_page(root: Path) -> str:
    lines = [
        "# Results on test-1k",
        "",
        "The built-in policies and the learned baseline in the closed loop on test-1k, scored by "
        "`scoring eval --paper`, beside the paper's published rows (measured on its Unity suite: a "
        "reference for scale, not a comparison on equal terms). Generated from the files in "
        "`benchmarks/results/` when the site is built; see [metrics](../reference/metrics.md) for "
        "the definitions.",
        "",
        provenance_note(root, "record.json") + " " + LEROBOT_NOTE,
        "",
        EPISODES_NOTE,
        "",
    ]
    for source in (*TEST_1K, BASELINE, LEROBOT):
        lines += _section(root, source, "files")
    return "\n".join(lines)


def test_complex_page(root: Path) -> str:
    lines = [
        "# Results on test-complex",
        "",
        "The harder scenes (projectile, obstacle, irregular; paper A.11) in the closed loop, and one "
        "frame strip of each. Generated from the files in `benchmarks/results/` when the site is built; "
        "see [harder scenes](../guides/harder-scenes.md).",
        "",
        provenance_note(root, "test_complex_record.json"),
        "",
    ]
    for source in TEST_COMPLEX:
        lines += _section(root, source, "files")
    return "\n".join(lines)


def script_summary(path: Path) -> str:
    """The first paragraph of a benchmark script's docstring, on one line."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    doc = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", doc)  # Sphinx roles (:mod:`x`) as plain code
    return " ".join(doc.split("\n\n")[0].split())


def _kept(root: Path, script: str) -> str:
    """Where a script's last result is shown (sections of this page or the results pages)."""
    pages = {**{s.name: "results/test-1k.md" for s in (*TEST_1K, BASELINE, LEROBOT)},
             **{s.name: "results/test-complex.md" for s in TEST_COMPLEX}}
    shown = []
    for source in (*TIMINGS, SCALING, *TEST_1K, BASELINE, LEROBOT, *TEST_COMPLEX):
        if source.script == script and (root / RESULTS / source.name).exists():
            page = pages.get(source.name, "")
            anchor = re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", source.title.lower()).strip())  # as toc's slugify
            shown.append(f"[`{source.name}`]({page}#{anchor})")
    return ", ".join(dict.fromkeys(shown)) or "none"


def benchmarks_page(root: Path) -> str:
    scripts = sorted(p for p in (root / "benchmarks").glob("*.py") if p.name != "bench_setup.py")
    lines = [
        "# Benchmarks",
        "",
        "Each script in `benchmarks/` measures against a bare baseline in the same run and prints "
        "JSON as its last line; the ones below keep their last result in `benchmarks/results/`. "
        "Times depend on the machine and its load: each section gives the load average its file "
        "records. Generated when the site is built.",
        "",
        "| script | what it measures | last result kept |",
        "|---|---|---|",
        *[f"| `{p.name}` | {script_summary(p).replace('|', chr(92) + '|')} | {_kept(root, p.name)} |"
          for p in scripts],
        "",
        "A script with no result kept prints its figures when run; none are quoted here, since a "
        "figure is only shown with the file (and the load average) it comes from.",
        "",
    ]
    for source in TIMINGS:
        lines += _section(root, source, FILES_URI)
    lines += scaling_section(root, FILES_URI)
    return "\n".join(lines)


def _seconds(value: float | None) -> str:
    if value is None:
        return "not measured"
    return f"{value * 1000:.1f} ms" if abs(value) < 1 else f"{value:.2f} s"


def scaling_section(root: Path, files: str) -> list[str]:
    """The scaling measurement and the projection it gives, from ``scaling.json`` alone (or
    a line saying it is not measured yet)."""
    path = root / RESULTS / SCALING.name
    lines = [f"## {SCALING.title}", ""]
    if not path.exists():
        return lines + [f"Not measured yet: run {_script_link(SCALING.script)} on a quiet machine to write "
                        f"`benchmarks/results/{SCALING.name}`; this section then shows the projection.", ""]
    record = json.loads(path.read_text(encoding="utf-8"))
    m, runs, target = record["measured"], record["runs"], record["target"]
    tiny = " **A `--tiny` check run: its numbers mean nothing.**" if record.get("tiny") else ""
    lines += [_source_line(root, SCALING, files), "", load_note(json.dumps(record)) + tiny, "",
              f"Measured on {record['date_utc']} UTC (commit {str(record.get('commit'))[:7]}, {record['cores']} cores), "
              f"{record['episodes']} episodes of `{record['slice']}` at {record['resolution']} px in shards of "
              f"{record['shard_size']} ({runs['workers_1']['frames']:,} frames), the overheads on "
              f"{record['tiny_shards']} one-episode shards:", "",
              "| quantity | value |", "|---|---|",
              f"| CPU per frame, in process | {_seconds(m['cpu_s_per_frame'])} |",
              f"| 1 local worker | {m['fps_1_worker']:.1f} frames/s |",
              f"| 2 local workers | {m['fps_2_workers']:.1f} frames/s |",
              f"| parallel efficiency at 2 workers | {m['parallel_efficiency']:.2f} |",
              f"| cluster start-up and shut-down | {_seconds(m['cluster_start_s'])} |",
              f"| scheduler, per shard | {_seconds(m['scheduler_s_per_shard'])} |",
              f"| upload to S3 on loopback (moto), per shard | {_seconds(m['upload_s_per_shard'])} |", "",
              f"Projected wall time of `{target['slice']}` ({target['episodes']:,} episodes, "
              f"{target['frames']:,} frames, {target['shards']:,} shards of {target['shard_size']}), "
              f"`{record['projection']['model']}`:", "",
              "| cores | projected wall time |", "|---|---|",
              *[f"| {cores} | {hours:.1f} h |" for cores, hours in record["projection"]["hours"].items()], "",
              f"What the model assumes is in the docstring of `benchmarks/{SCALING.script}`.", ""]
    return lines


def _headline(root: Path, name: str) -> list[str]:
    """The first table of a scores file (its ``## Scores`` section), without the breakdowns."""
    path = root / RESULTS / name
    if not path.exists():
        return [f"`benchmarks/results/{name}` is not written yet.", ""]
    text = path.read_text(encoding="utf-8")
    first = text.split("\n### ")[0]
    return [re.sub(r"^## .*\n", "", first).strip(), ""]


def results_index_page(root: Path) -> str:
    lines = [
        "# Results",
        "",
        "How the built-in policies, the learned baseline and the ground truth score in Dyana's closed "
        "loop, beside the paper's published rows. Every table is generated from the files in "
        "`benchmarks/results/` when the site is built (nothing here is typed by hand); the pages below "
        "add the breakdowns by motion type, interception setting and object, the plots, and the "
        "scripts that wrote them. The metrics are defined in [metrics](../reference/metrics.md); how to "
        "produce such a run yourself: [evaluate a policy](../guides/evaluate.md).",
        "",
        "## test-1k",
        "",
        "Breakdowns, radar and latency plots, the learned baseline's training record: "
        "[results on test-1k](test-1k.md).",
        "",
        *_headline(root, "table.md"),
        "## test-complex",
        "",
        "The harder scenes (projectile, obstacle, irregular), with frame strips: "
        "[results on test-complex](test-complex.md).",
        "",
        *_headline(root, "test_complex_table.md"),
        "How fast the pipeline, the loader and the closed loop are: [benchmarks](../benchmarks.md).",
        "",
    ]
    return "\n".join(lines)


#: Generated page (relative to docs/) -> its renderer.
PAGES = {
    "results/index.md": results_index_page,
    "results/test-1k.md": test_1k_page,
    "results/test-complex.md": test_complex_page,
    "benchmarks.md": benchmarks_page,
}


def published_files(root: Path) -> dict[str, Path]:
    """Result files copied into the site (the pages link to them): site path -> file."""
    out = {}
    for path in sorted((root / RESULTS).rglob("*")):
        rel = path.relative_to(root / RESULTS)
        if path.is_file() and path.suffix not in UNPUBLISHED and rel.parts[0] != "runs":
            out[f"{FILES_URI}/{rel.as_posix()}"] = path
    return out


FIRST_SCREEN = RESULTS / "first_screen.json"


def _duration(seconds: float) -> str:
    whole = round(seconds)
    return f"{whole} s" if whole < 60 else f"{whole // 60} min {whole % 60:02d} s"


def first_screen_sentence(root: Path) -> str:
    """The README's sentence on how long its two commands take, from first_screen.json only."""
    path = root / FIRST_SCREEN
    if not path.exists():
        return ("Timings: not measured yet. `python benchmarks/first_screen.py` times both commands "
                "in a fresh clone and writes `benchmarks/results/first_screen.json`.")
    record = json.loads(path.read_text(encoding="utf-8"))
    one, two = record["command_1"], record["command_2"]
    phases = two.get("phases", {})
    tests, manual = phases.get("tests"), phases.get("manual")
    of_which = f", of which the tests {_duration(tests)}{_stolen(two)}" if tests is not None else ""
    if tests is not None and manual is not None:
        of_which += f", and the manual's pages (a step of their own) {_duration(manual)}"
    return (f"Timings (`benchmarks/results/first_screen.json`, {record['date_utc']}, commit "
            f"{record['commit'][:7]}, {record['cores']} cores, load average {record['load_average_start'][0]} "
            f"at the start and {record['load_average_end'][0]} at the end, pip's cache "
            f"{record['pip_cache']}): command 1 took {_duration(one['seconds'])} with the install, "
            f"command 2 {_duration(two['seconds'])}{of_which}{_probe(record)}.")


def _stolen(command: dict) -> str:
    """The CPU seconds the host took from this virtual machine during the tests, where measured."""
    machine = (command.get("phases_machine_cpu") or {}).get("tests")
    if not machine:
        return ""
    return (f", in which the machine was busy for {machine['busy_cpu_s']:,.0f} CPU s and its host took "
            f"{machine['steal_cpu_s']:,.0f} CPU s from it (steal, `/proc/stat`)")


def _probe(record: dict) -> str:
    """The bare baseline of a first-screen run, where it was measured (this machine's speed)."""
    if "bare_probe_s_start" not in record:
        return ""
    return (f" (the bare baseline, {record['bare_probe_terms']:,} squares summed in plain Python, took "
            f"{record['bare_probe_s_start']} CPU s at the start and {record['bare_probe_s_end']} at the end)")
