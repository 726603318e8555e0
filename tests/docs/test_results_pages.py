"""The results pages show today's dataset: every scored run and every figure is of the
current dataset version, each table has one chance row, and no raw markup reaches a page."""

from __future__ import annotations

import json
import re
import sys

import pytest

from schemas.versions import DATASET_VERSION
from tests.docs.pages import ROOT

sys.path.insert(0, str(ROOT / "docs" / "hooks"))
import results_pages  # noqa: E402  (docs/hooks is no package: the hook modules are found by path)

RESULTS = ROOT / results_pages.RESULTS
RECORDS = ("record.json", "test_complex_record.json")
CHANCE_ROW = re.compile(r"^\| chance \(best blind\) \|", re.M)


@pytest.mark.parametrize("name", RECORDS)
def test_every_scored_run_is_of_todays_dataset_version(name: str) -> None:
    record = json.loads((RESULTS / name).read_text(encoding="utf-8"))
    stale = {run: info["dataset_version"] for run, info in record["runs"].items() if info["dataset_version"] != DATASET_VERSION}
    assert not stale, f"{name}: runs of another dataset version than {DATASET_VERSION} (rerun closed_loop_results.py): {stale}"
    assert record["scored"]["dataset_version"] == DATASET_VERSION


def test_every_figure_on_the_results_pages_names_a_record_of_todays_version() -> None:
    for source in (*results_pages.TEST_1K, *results_pages.TEST_COMPLEX):
        if source.name.endswith(".png"):
            assert source.record is not None, f"{source.name}: a figure needs the record of its commit and load"
            record = json.loads((RESULTS / source.record).read_text(encoding="utf-8"))
            found = results_pages.record_provenance(record)
            assert found is not None and found["dataset_version"] == DATASET_VERSION, source.record
            assert list(results_pages.load_values(record)), f"{source.record} records no load"


@pytest.mark.parametrize("page", ["results/index.md", "results/test-1k.md", "results/test-complex.md"])
def test_a_results_page_has_one_chance_row_per_table_and_no_raw_markup(page: str) -> None:
    text = results_pages.PAGES[page](ROOT)
    tables, current = [], []
    for line in [*text.splitlines(), ""]:  # a table: consecutive lines that start with "|"
        if line.startswith("|"):
            current.append(line)
        elif current:
            tables.append("\n".join(current))
            current = []
    for table in tables:
        assert len(CHANCE_ROW.findall(table)) <= 1, f"{page}: a table with two chance rows:\n{table[:400]}"
    assert len(CHANCE_ROW.findall(text)) >= 1, f"{page}: no chance row"
    assert not re.search(r":(mod|class|func|meth|data):`", text), f"{page}: a raw Sphinx role"
    assert "predate" not in text and "3.0.0's frames" not in text, f"{page}: a note about older runs"
