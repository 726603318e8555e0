"""``scoring.io.from_recordings``: bad arguments are a SpecError naming the argument,
raised before anything is stacked."""

from __future__ import annotations

import pytest

from schemas.errors import SpecError
from scoring.io import from_recordings
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
