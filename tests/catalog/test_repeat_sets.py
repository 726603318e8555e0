"""A folder of repeats given to a reader of one run (``catalog.open``, ``pipeline replay``,
``catalog verify``, ``catalog export``, ``pipeline view``): one line saying what it is, its
repeats, and one to pass instead."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import catalog
from pipeline.cli import main as pipeline_main
from pipeline.cli_catalog import main as catalog_main
from schemas.errors import ShardError

from .conftest import SETTINGS
from .test_info import rollout_folder


@pytest.fixture
def repeats(tmp_path: Path) -> Path:
    root = tmp_path / "rob"
    runs = []
    for r in range(3):
        manifest = rollout_folder(root / f"repeat-{r:02d}", SETTINGS)
        runs.append({"path": f"repeat-{r:02d}", "hash": manifest.hash})
    (root / "repeats.json").write_text(json.dumps({"repeats": 3, "runs": runs}))
    return root


def test_catalog_open_names_the_repeats_and_one_to_pass(repeats):
    with pytest.raises(ShardError) as caught:
        catalog.open(repeats)
    assert str(caught.value) == (
        f"{repeats} is a folder of 3 repeats (repeat-00 ... repeat-02, indexed by repeats.json), not one run: "
        f"pass one of them, e.g. {repeats / 'repeat-00'} (`scoring eval {repeats}` scores them together)"
    )
    with catalog.open(repeats / "repeat-00") as dataset:  # what the message says works
        assert len(dataset.episodes) == 2


@pytest.mark.parametrize("main, args", [
    (pipeline_main, ["replay"]), (catalog_main, ["verify"]), (catalog_main, ["export", "--out", "{tmp}/exp"]),
    (pipeline_main, ["view", "--out", "{tmp}/one.rrd"]),
])
def test_each_reader_of_one_run_says_the_same(repeats, tmp_path, capsys, main, args):
    argv = [args[0], str(repeats), *(a.format(tmp=tmp_path) for a in args[1:])]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a folder of 3 repeats (repeat-00 ... repeat-02" in err, err
    assert f"e.g. {repeats / 'repeat-00'}" in err and not (tmp_path / "exp").exists()
