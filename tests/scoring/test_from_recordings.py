"""``scoring.io.from_recordings``: bad arguments are a SpecError naming the argument,
raised before anything is stacked."""

from __future__ import annotations

import pytest

from schemas.errors import SpecError
from scoring.io import from_recordings
from scoring.report import report_dict, score_run
from tests.catalog.conftest import make_episode


@pytest.fixture(scope="module")
def pair():
    spec, frames, _ = make_episode(0)
    return spec, frames


def test_good_arguments_make_a_run(pair):
    spec, frames = pair
    run = from_recordings("gt", "linear-fast", [spec], [frames])
    assert run.name == "gt" and list(run.episode_index) == [spec.episode_index]


@pytest.mark.parametrize(
    "change, message",
    [
        ({"specs": []}, "specs must hold at least one EpisodeSpec"),
        ({"specs": "abc"}, "specs must be a list of EpisodeSpec, got 'abc'"),
        ({"specs": None}, "specs must be a list of EpisodeSpec, got None"),
        ({"specs": [42]}, r"specs\[0\] must be an EpisodeSpec, got 42"),
        ({"recordings": []}, r"recordings must hold one EpisodeFrames per spec \(1\), got 0"),
        ({"recordings": [None]}, r"recordings\[0\] must be an EpisodeFrames, got None"),
        ({"recordings": 7}, "recordings must be a list of EpisodeFrames, got 7"),
        ({"errors": [None, None]}, r"errors must have one entry per spec \(1\), got 2"),
        ({"errors": [3]}, r"errors\[0\] must be a str or None, got 3"),
        ({"name": None}, "name must be a str, got None"),
        ({"slice_name": 5}, "slice_name must be a str, got 5"),
        ({"policy": 1.5}, "policy must be a str or None, got 1.5"),
    ],
)
def test_bad_arguments_are_a_spec_error_naming_the_argument(pair, change, message):
    spec, frames = pair
    arguments = {"name": "run", "slice_name": "linear-fast", "specs": [spec], "recordings": [frames],
                 "policy": "oracle", "errors": [None], **change}
    with pytest.raises(SpecError, match=message):
        from_recordings(**arguments)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda run: score_run(None), "data must be a RunData"),
        (lambda run: score_run("run-folder"), "data must be a RunData"),
        (lambda run: score_run(run, 5), "label must be text or None, got 5"),
        (lambda run: score_run(run, reading="x" * 10_000), r"reading must be one of \['dyana', 'lenient', 'paper'\], got 'xxx.*characters\)$"),
        (lambda run: score_run(run, reading={}), r"reading must be one of .*got \{\}"),
        (lambda run: score_run(run, reading=None), "reading must be one of .*got None"),
        (lambda run: score_run(run, obstacle_contact=[]), r"obstacle_contact must be one of .*got \[\]"),
        (lambda run: report_dict(None), "report must be a RunReport"),
        (lambda run: report_dict(run), "report must be a RunReport"),
    ],
)
def test_score_run_and_report_dict_name_a_bad_argument(pair, call, message):
    """Before: AttributeError ('NoneType' object has no attribute 'offsets'), a plain
    ValueError for an unknown reading and a TypeError for an unhashable one."""
    spec, frames = pair
    run = from_recordings("gt", "linear-fast", [spec], [frames])
    with pytest.raises(SpecError, match=message):
        call(run)
