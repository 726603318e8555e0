"""The irregular-to-regular setting (paper A.11): joins, timing, determinism, feasibility,
the slices' statistics and byte-identical builds."""

from __future__ import annotations

import json

import numpy as np
import pytest

from generators.irregular import REGULAR, choices, irregular_motion
from generators.recipe import slice_specs, slice_summary, spec_for
from generators.tracks import curvature, evaluate
from pipeline import episode
from schemas.errors import SpecError
from schemas.motion import LineToken, Motion, Track
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

EPS = 1e-7


@pytest.mark.parametrize("family", REGULAR)
def test_the_chain_joins_its_regular_token_with_continuous_position_velocity_and_curvature(family):
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([7, REGULAR.index(family)])))
    motion = irregular_motion(rng, family, observe_s=1.5, total_s=3.0)
    kinds = [t.type for t in motion.base.tokens]
    assert set(kinds[:-1]) == {"C"} and kinds[-1] == family
    join = 1.5
    before, after = evaluate(motion, [join - EPS, join + EPS]), evaluate(motion, [join])
    np.testing.assert_allclose(before.position[0], before.position[1], atol=1e-5)
    np.testing.assert_allclose(before.velocity[0], before.velocity[1], atol=1e-4)
    assert after.position.shape == (1, 2)
    k = curvature(motion, [join - 1e-4, join + 1e-4], signed=True)
    assert abs(k[0] - k[1]) < 1e-2, k


def test_the_regular_motion_starts_at_the_first_acting_frame():
    for spec in slice_specs("test-irregular", 9):
        clothoids = [t for t in spec.motion.base.tokens if t.type == "C"]
        assert sum(t.duration for t in clothoids) == pytest.approx(spec.observe_frames / FPS, abs=1e-9)
        assert spec.rollout_format == "observe-before-act" and spec.motion_type == "irregular"


def test_episodes_are_deterministic_and_independent_of_each_other():
    batch = list(slice_specs("irregular-medium", 6))
    assert spec_for("irregular-medium", 5).to_json() == batch[5].to_json()
    assert spec_for("irregular-medium", 5).to_json() == spec_for("irregular-medium", 5).to_json()


def test_ground_truth_intercepts_every_cell_within_tolerance():
    specs = list(slice_specs("test-irregular", 9))
    assert {(s.intercept_setting, s.motion.base.tokens[-1].type) for s in specs} == {
        (setting, family) for setting in ("fast", "medium", "slow") for family in REGULAR
    }
    for spec in specs:
        frames = episode(spec)
        i = spec.intercept_frame
        assert frames.palm_distance[i] <= 1e-4
        assert frames.palm_distance[i - 1] > frames.palm_distance[i]


def test_stats_come_from_the_choices_and_agree_with_the_specs():
    fast = slice_summary("irregular-fast", 12)
    specs = list(slice_specs("irregular-fast", 12))
    assert fast["total_frames"] == sum(s.num_frames for s in specs)
    assert fast["objects"]["categories"] == len({s.object for s in specs})
    assert fast["motion_types"]["irregular"]["episodes"] == 12
    assert fast["motion_types"]["irregular"]["mean_frames"] == pytest.approx(
        np.mean([choices(2001, i, "fast")[0].common.num_frames for i in range(12)])
    )


def test_a_spec_is_irregular_only_when_its_tokens_make_it_so():
    spec = json.loads(spec_for("irregular-fast", 0).to_json())
    EpisodeSpec.from_dict(spec)
    line = Motion(Track((LineToken(start=(0.0, 4.0), direction=0.0, speed=1.0, acceleration=0.0, duration=3.0),)))
    spec["motion"] = json.loads(json.dumps({"base": [{"type": "L", "start": [0.0, 4.0], "direction": 0.0,
                                                      "speed": 1.0, "acceleration": 0.0, "duration": 3.0}]}))
    with pytest.raises(SpecError, match="contradicts the motion's tokens"):
        EpisodeSpec.from_dict(spec)
    assert line.base.tokens[0].type == "L"


def test_the_dataloader_selects_irregular_episodes(tmp_path):
    import catalog
    from pipeline.jobs.build import build

    build("irregular-fast", tmp_path, episodes=2, shard_size=2, resolution=32, workers=1, progress=False)
    with catalog.open(tmp_path / "irregular-fast", motion_type="irregular") as ds:
        assert len(ds.episodes) == 2 and {e.motion_type for e in ds.episodes} == {"irregular"}
    with pytest.raises(SpecError, match=r"no episode matches the filters \(motion_type=\['linear'\]\)"):
        catalog.open(tmp_path / "irregular-fast", motion_type="linear")  # refused, saying what the folder holds
