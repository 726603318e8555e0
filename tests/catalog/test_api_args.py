"""catalog.open and open_folder refuse a wrong type or size of each argument with a
SpecError naming it, before any folder is read (so before anything is allocated)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

import catalog
from catalog.loader.opening import MAX_CACHE_MB, MAX_RESIZE
from catalog.tables.reader import open_folder
from schemas.errors import SpecError

BAD = [
    ({"paths": 42}, "paths"),
    ({"paths": None}, "paths"),
    ({"paths": [42]}, "paths"),
    ({"paths": [b"folder"]}, "paths"),
    ({"paths": "s3://"}, "bucket"),
    ({"paths": ["s3:///"]}, "bucket"),
    ({"motion_type": 5}, "motion_type"),
    ({"motion_type": [5, "linear"]}, "motion_type"),
    ({"motion_type": [["linear"]]}, "motion_type"),
    ({"intercept_setting": 3}, "intercept_setting"),
    ({"intercept_setting": {"fast": 1}}, "intercept_setting"),
    ({"object": 7}, "object"),
    ({"episodes": 1.5}, "episodes"),
    ({"episodes": "3"}, "episodes"),
    ({"episodes": [1.0]}, "episodes"),
    ({"where": "x"}, "where"),
    ({"where": 3}, "where"),
    ({"cache_mb": math.inf}, "cache_mb"),
    ({"cache_mb": MAX_CACHE_MB + 1}, "cache_mb"),
    ({"history": 10**12}, "history"),
    ({"action_horizon": 10**12}, "action_horizon"),
    ({"resize": 10**6}, "resize"),
    ({"resize": MAX_RESIZE + 1}, "resize"),
    ({"resize": "64"}, "resize"),
    ({"resize": ("64", "64")}, "resize"),
    ({"resize": (64, 64, 3)}, "resize"),
    ({"resize": (64.0, 64)}, "resize"),
]


@pytest.mark.parametrize(("kwargs", "named"), BAD, ids=[repr(k) for k, _ in BAD])
def test_a_bad_argument_is_refused_naming_it_before_reading(tmp_path, kwargs, named):
    """The folder does not exist: the argument is refused before it is looked at."""
    kwargs = {"paths": str(tmp_path / "absent"), **kwargs}
    with pytest.raises(SpecError, match=named):
        catalog.open(**kwargs)


def test_windows_longer_than_the_longest_episode_are_refused(built):
    longest = max(e.num_frames for e in catalog.open(built).episodes)
    assert len(catalog.open(built, history=longest, action_horizon=longest)) > 0
    with pytest.raises(SpecError, match="history"):
        catalog.open(built, history=longest + 1)
    with pytest.raises(SpecError, match="action_horizon"):
        catalog.open(built, action_horizon=longest + 1)


def test_the_largest_resize_is_accepted(built):
    ds = catalog.open(built, resize=(MAX_RESIZE, 8))
    assert ds[0]["image"].shape == (MAX_RESIZE, 8, 3)


def test_select_checks_its_filters_too(built):
    ds = catalog.open(built)
    with pytest.raises(SpecError, match="where"):
        ds.select(where=1)
    with pytest.raises(SpecError, match="motion_type"):
        ds.select(motion_type=5)


def test_open_folder_verify_mode(built):
    with pytest.raises(SpecError, match="verify"):
        open_folder(built, verify="md5")
    with pytest.raises(SpecError, match="verify"):
        open_folder(Path("/nonexistent"), verify="md5")
    with pytest.raises(ValueError):  # still a ValueError for callers that caught one
        open_folder(built, verify="md5")
