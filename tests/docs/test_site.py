"""What keeps the manual honest besides running it: the README's length, links that
resolve, markers that mean something, the generated pages, and versions that agree."""

from __future__ import annotations

import re
import sys

import pytest

from schemas.versions import CODE_VERSION
from tests.docs.pages import FENCE, MARKER, MARKER_KINDS, ROOT, RUN_LANGUAGES, Marker, load, page_paths
from tests.docs.runner import runnable

sys.path.insert(0, str(ROOT / "docs" / "hooks"))
import results_pages  # noqa: E402  (docs/hooks is no package: the hook modules are found by path)
import site_pages  # noqa: E402

README_MAX_LINES = 200
LINK = re.compile(r"!?\[[^\]]*\]\((?P<target><[^>]+>|[^)\s]+)(?:\s+\"[^\"]*\")?\)")
REFERENCE = re.compile(r"^\s*\[[^\]]+\]:\s*(?P<target>\S+)", re.M)
FENCED = re.compile(r"^(\s*)(`{3,}|~{3,}).*?^\1\2\s*$", re.M | re.S)
INLINE_CODE = re.compile(r"`[^`\n]*`")


def test_readme_is_at_most_200_lines() -> None:
    lines = len((ROOT / "README.md").read_text(encoding="utf-8").splitlines())
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines (at most {README_MAX_LINES}): move the rest to docs/"


def _links(text: str) -> list[str]:
    prose = INLINE_CODE.sub("", FENCED.sub("", text))
    return [m.group("target").strip("<>") for m in (*LINK.finditer(prose), *REFERENCE.finditer(prose))]


def _site_files() -> set[str]:
    """Every path (relative to docs/) that the built site has: pages on disk and generated ones."""
    on_disk = {p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*") if p.is_file()}
    return on_disk | set(site_pages.GENERATED) | set(results_pages.published_files(ROOT))


@pytest.mark.parametrize("path", page_paths())
def test_relative_links_resolve(path: str) -> None:
    site = _site_files()
    broken = []
    for target in _links((ROOT / path).read_text(encoding="utf-8")):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # a URL or an anchor on the same page
        file = target.split("#")[0]
        resolved = (ROOT / path).parent / file
        in_docs = resolved.resolve().is_relative_to((ROOT / "docs").resolve())
        relative = resolved.resolve().relative_to((ROOT / "docs").resolve()).as_posix() if in_docs else None
        if not (resolved.exists() or (relative is not None and relative in site)):
            broken.append(target)
    assert not broken, f"{path}: links to missing files: {broken}"


def _markers() -> list[tuple[str, int, Marker, bool]]:
    """(page, line, marker, right before a bash/python fence) of every docs-test marker."""
    out = []
    for path in page_paths():
        lines = (ROOT / path).read_text(encoding="utf-8").splitlines()
        for i, line in enumerate(lines):
            match = MARKER.match(line)
            if match:
                fence = FENCE.match(lines[i + 1]) if i + 1 < len(lines) else None
                before_block = fence is not None and fence.group("info").lower() in RUN_LANGUAGES
                out.append((path, i + 1, Marker.parse(match.group("body")), before_block))
    return out


def _names_a_cover(argument: str) -> bool:
    """``(covered by tests/x.py[::test] and ...)``: the faster test(s) that cover a slow block."""
    found = re.fullmatch(r"\(covered by (tests/\S+?\.py)(::\w+)?\b.*\)", argument)
    return found is not None and (ROOT / found.group(1)).is_file()


def test_markers_are_well_formed() -> None:
    wrong = []
    for path, line, marker, before_block in _markers():
        where = f"{path}:{line}"
        if marker.kind not in MARKER_KINDS:
            wrong.append(f"{where}: unknown marker {marker.kind!r} (known: {', '.join(MARKER_KINDS)})")
        elif marker.kind in ("needs", "skip") and not marker.argument:
            wrong.append(f"{where}: `{marker.kind}` needs a {'module' if marker.kind == 'needs' else 'reason'}")
        elif marker.kind == "slow" and marker.cover and not _names_a_cover(marker.cover):
            wrong.append(f"{where}: `slow` takes nothing or '[needs MODULE] (covered by tests/FILE.py...)' naming a "
                         f"test file that exists, got {marker.argument!r}")
        if not before_block:
            wrong.append(f"{where}: a docs-test marker must be on the line right before a ```bash or ```python fence")
    assert not wrong, "\n".join(wrong)


def _skips() -> list:
    return [pytest.param(p, n, m.argument, id=f"{p}:{n}") for p, n, m, _ in _markers() if m.kind == "skip"]


@pytest.mark.parametrize("path,line,reason", _skips())
def test_skip_marker(path: str, line: int, reason: str) -> None:
    """A `docs-test: skip` block is one the runner leaves out, even with the slow blocks,
    for the marker's reason; then this test is skipped, so every run's summary lists the
    blocks not run with their reasons."""
    block = next((b for b in load(path).blocks if b.line == line + 1), None)
    assert block is not None, f"{path}:{line}: no ```bash or ```python block right after the skip marker"
    why = runnable(block, with_slow=True)
    assert why == f"skip: {reason}", f"{block.where}: marked skip, but the runner says {why!r} (None: it runs the block)"
    pytest.skip(f"docs block not run: {path}:{line}: {reason}")


def test_every_page_has_runnable_or_no_blocks() -> None:
    """A page's blocks parse: the fences close, so no block silently swallows the rest of a page."""
    for path in page_paths():
        text = (ROOT / path).read_text(encoding="utf-8")
        fences = [line for line in text.splitlines() if re.match(r"^\s*`{3,}", line)]
        assert len(fences) % 2 == 0, f"{path}: an unclosed ``` fence"
        load(path)


@pytest.mark.parametrize("uri", sorted(site_pages.GENERATED))
def test_generated_page_renders(uri: str) -> None:
    text = site_pages.GENERATED[uri](ROOT)
    assert text.startswith("# "), f"{uri} has no title"
    assert not (ROOT / "docs" / uri).exists(), f"docs/{uri} is generated at build time: do not commit a copy"


def test_cli_reference_has_every_subcommand() -> None:
    import cli_reference  # noqa: PLC0415  (docs/hooks, found by path above)

    text = cli_reference.render(ROOT)
    for program, entry in cli_reference.console_scripts(ROOT).items():
        for name, _, sub in cli_reference.subcommands(cli_reference.parser_of(entry)):
            assert f"### {program} {name}" in text
            for action in cli_reference.arguments(sub):
                for option in action.option_strings:
                    assert f"`{option}" in text or f", {option}" in text, f"{program} {name} {option} missing"
    assert "OUT/&lt;slice&gt;/" in text  # before: "OUT//", <slice> taken for an HTML tag
    assert "one per core;" in text and not re.search(r"\d here", text)  # before: the docs machine's "2 here"


def test_every_timing_file_shows_its_load() -> None:
    page = results_pages.benchmarks_page(ROOT)
    for source in results_pages.TIMINGS:
        path = ROOT / results_pages.RESULTS / source.name
        if path.exists():
            for record in results_pages.json_records(path.read_text(encoding="utf-8")):
                for _, value in results_pages.load_values(record):
                    assert str(value) in page, f"{source.name}: load average {value} not on the benchmarks page"


def test_readme_timing_sentence_comes_from_the_results_file() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    marked = re.search(r"<!-- first-screen -->\n(.*?)\n<!-- /first-screen -->", readme, re.S)
    assert marked, "README.md lost its <!-- first-screen --> ... <!-- /first-screen --> lines"
    assert marked.group(1) == results_pages.first_screen_sentence(ROOT), (
        "README.md's timing sentence differs from benchmarks/results/first_screen.json: "
        "run `python benchmarks/first_screen.py --update-readme`")


def test_changelog_newest_release_is_the_package_version() -> None:
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    released = re.findall(r"^## \[(\d+\.\d+\.\d+[^\]]*)\]", changelog, re.M)
    assert released, "CHANGELOG.md has no released version heading (## [X.Y.Z] - DATE)"
    assert released[0] == CODE_VERSION, (
        f"CHANGELOG.md's newest release is {released[0]}, the package (schemas.versions.CODE_VERSION) is {CODE_VERSION}")
