"""``pipeline eval --repeats``: a run where every episode of every repeat failed exits as a
single such run does (AllEpisodesFailed, exit 3), after writing the repeats and their index."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.jobs.repeats import evaluate_repeats
from pipeline.loop.conditions import EvalProtocol
from schemas.errors import AllEpisodesFailed

RESOLUTION = 32
FAILING = "tests.pipeline.faulty_policies:RaiseFault"


def test_every_episode_of_every_repeat_failed_raises_after_writing(tmp_path):
    out = tmp_path / "rob"
    with pytest.raises(AllEpisodesFailed, match=r"in each of the 2 repeats every episode failed \(1 of 1\)"):
        evaluate_repeats(FAILING, "test-1k", out, 2, EvalProtocol(), episodes=1, workers=0, resolution=RESOLUTION,
                         isolate=False, progress=False, summary=False, require_success=True)
    index = json.loads((out / "repeats.json").read_text())
    assert [r["path"] for r in index["runs"]] == ["repeat-00", "repeat-01"]
    assert all((out / r["path"] / "catalog.json").is_file() for r in index["runs"])


def test_repeats_where_some_episode_ran_return_their_manifests(tmp_path):
    manifests = evaluate_repeats("still", "test-1k", tmp_path / "rob", 2, EvalProtocol(), episodes=1, workers=0,
                                 resolution=RESOLUTION, progress=False, summary=False, require_success=True)
    assert len(manifests) == 2


@pytest.mark.slow(cover="tests/pipeline/test_repeats.py::test_every_episode_of_every_repeat_failed_raises_after_writing")
def test_the_command_line_exits_3_when_every_repeat_failed(tmp_path):
    out = tmp_path / "rob"
    result = subprocess.run(
        [str(Path(sys.executable).parent / "pipeline"), "eval", "--policy", FAILING, "--in-process", "--slice", "test-1k",
         "--episodes", "1", "--workers", "1", "--resolution", str(RESOLUTION), "--repeats", "2", "--quiet",
         "--out", str(out)],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 3, result.stderr
    assert result.stderr.count("\n") == 1 and "every episode failed" in result.stderr and "2 repeats" in result.stderr
    assert (out / "repeats.json").is_file()
