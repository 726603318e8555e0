"""EpisodeSpec: JSON round trips, hash, JSONL loading and validation messages."""

from __future__ import annotations

import json

import pytest

from schemas.errors import SpecError
from schemas.motion import ArcToken, HarmonicToken, LineToken, Motion, Track
from schemas.scene import GRASP_FRAMES
from schemas.spec import SPEC_FIELDS, EpisodeSpec, read_specs_jsonl


def spec_dict(**changes) -> dict:
    out = {
        "slice": "linear-fast",
        "episode_index": 42,
        "seed": 7,
        "motion_type": "linear",
        "motion": {"base": [{"type": "L", "start": [0.0, 3.0], "direction": 0.5, "speed": 1.0, "acceleration": 0.0, "duration": 2.0}]},
        "object": "tennis_ball",
        "object_size": 0.6,
        "hand": "right",
        "rollout_format": "observe-before-act",
        "intercept_setting": "fast",
        "observe_frames": 10,
        "num_frames": 36,
        "text": "Pick up the tennis ball rolling in a straight line.",
    }
    out.update(changes)
    return out


def test_round_trip_and_canonical_json():
    spec = EpisodeSpec.from_dict(spec_dict())
    text = spec.to_json()
    assert EpisodeSpec.from_json(text) == spec
    assert EpisodeSpec.from_json(text).to_json() == text
    assert list(json.loads(text)) == sorted(SPEC_FIELDS)
    assert " " not in text.replace(spec.text, "")
    assert len(spec.spec_hash) == 64 and spec.spec_hash == EpisodeSpec.from_json(text).spec_hash
    assert EpisodeSpec.from_dict(spec_dict(seed=8)).spec_hash != spec.spec_hash


def test_round_trip_with_every_token_and_overlays():
    motion = Motion(
        Track((LineToken((0.0, 3.0), 0.5, 1.0, 0.0, 1.0), ArcToken((0.0, 0.0), 1.0, 1.0, 0.0, -1, 1.0))),
        (Track((HarmonicToken((0.0, 0.0), 1.0, 0.2, 2.0, 0.0, 1.0, (0.1, 0.0)),), 0.5),),
    )
    spec = EpisodeSpec(**{**spec_dict(), "motion": motion, "motion_type": "custom"})
    assert EpisodeSpec.from_json(spec.to_json()) == spec
    assert EpisodeSpec.from_json(spec.to_json()).motion.token_types == "LA"


def test_derived_properties():
    spec = EpisodeSpec.from_dict(spec_dict())
    assert spec.episode_id == "linear-fast:000042"
    assert spec.intercept_time_s == 0.5
    assert spec.approach_frames == 10
    assert spec.intercept_frame == 20
    assert spec.rolling is True
    assert spec.fps == 20
    direct = EpisodeSpec.from_dict(spec_dict(rollout_format="direct-act", observe_frames=0, intercept_setting="slow", num_frames=40))
    assert direct.intercept_frame == 30
    assert EpisodeSpec.from_dict(spec_dict(object="mug", object_size=0.9)).rolling is False


def test_integral_floats_are_accepted_as_integers():
    spec = EpisodeSpec.from_dict(spec_dict(episode_index=3.0))
    assert spec.episode_index == 3 and isinstance(spec.episode_index, int)


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("slice", "", r"spec.slice must be a name of 1-64 characters.*got ''"),
        ("slice", "../../victim/linear-slow", r"spec.slice must be a name .*never a path.*'../../victim/linear-slow'"),
        ("slice", "/abs/path", r"never a path"),
        ("slice", "a/b", r"never a path"),
        ("slice", ".", r"never a path"),
        ("slice", "x\x00y", r"never a path"),
        ("episode_index", -1, r"spec.episode_index must be >= 0, got -1"),
        ("episode_index", 2.5, r"spec.episode_index must be an integer, got 2.5"),
        ("seed", True, r"spec.seed must be an integer, got True"),
        ("seed", "7", r"spec.seed must be an integer, got '7'"),
        ("motion_type", "spiral", r"spec.motion_type must be one of .*, got 'spiral'"),
        ("object", "teapot", r"unknown object 'teapot'"),
        ("object", ["tennis_ball"], r"spec.object must be an object category name, got \['tennis_ball'\]"),
        ("object_size", 0.0, r"spec.object_size must be a finite number > 0, got 0.0"),
        ("object_size", -0.5, r"spec.object_size must be a finite number > 0, got -0.5"),
        ("object_size", float("inf"), r"spec.object_size must be a finite number > 0, got inf"),
        ("hand", "both", r"spec.hand must be one of \['right', 'left'\], got 'both'"),
        ("rollout_format", "replay", r"spec.rollout_format must be one of .*, got 'replay'"),
        ("intercept_setting", "instant", r"spec.intercept_setting must be one of .*, got 'instant'"),
        ("observe_frames", -3, r"spec.observe_frames must be >= 0, got -3"),
        ("observe_frames", 0, r"spec.observe_frames must be >= 1 for observe-before-act, got 0"),
        ("num_frames", 20, rf"spec.num_frames must be >= {20 + GRASP_FRAMES + 1}, got 20"),
        ("num_frames", 80, r"spec.motion lasts 2.000 s but 80 frames need 3.950 s"),
        ("text", None, r"spec.text must be a string, got None"),
        ("motion", "L", r"motion must be an object with 'base', got 'L'"),
    ],
)
def test_bad_fields_name_the_field_and_the_value(field, value, message):
    with pytest.raises(SpecError, match=message):
        EpisodeSpec.from_dict(spec_dict(**{field: value}))


def test_direct_act_must_not_observe():
    with pytest.raises(SpecError, match=r"spec.observe_frames must be 0 for direct-act, got 10"):
        EpisodeSpec.from_dict(spec_dict(rollout_format="direct-act"))


def test_nan_in_json_text_is_rejected():
    text = json.dumps(spec_dict())
    with pytest.raises(SpecError, match=r"spec.object_size must be a finite number > 0, got nan"):
        EpisodeSpec.from_json(text.replace('"object_size": 0.6', '"object_size": NaN'))
    with pytest.raises(SpecError, match=r"spec.motion.base\[0\].direction must be finite, got nan"):
        EpisodeSpec.from_json(text.replace('"direction": 0.5', '"direction": NaN'))
    with pytest.raises(SpecError, match=r"spec.seed must be an integer, got inf"):
        EpisodeSpec.from_json(text.replace('"seed": 7', '"seed": Infinity'))


def test_missing_and_unknown_fields_are_named():
    data = spec_dict()
    del data["hand"]
    with pytest.raises(SpecError, match=r"spec is missing field\(s\) \['hand'\]"):
        EpisodeSpec.from_dict(data)
    with pytest.raises(SpecError, match=r"spec has unknown field\(s\) \['fps'\]"):
        EpisodeSpec.from_dict(spec_dict(fps=20))
    with pytest.raises(SpecError, match=r"spec.motion.base\[0\] \(L\) is missing field\(s\) \['speed'\]"):
        motion = {"base": [{"type": "L", "start": [0.0, 3.0], "direction": 0.5, "acceleration": 0.0, "duration": 2.0}]}
        EpisodeSpec.from_dict(spec_dict(motion=motion))
    with pytest.raises(SpecError, match=r"a spec must be a JSON object, got \[\]"):
        EpisodeSpec.from_json("[]")
    with pytest.raises(SpecError, match="spec is not valid JSON"):
        EpisodeSpec.from_json("{")


def test_read_specs_jsonl(tmp_path):
    path = tmp_path / "specs.jsonl"
    specs = [EpisodeSpec.from_dict(spec_dict(episode_index=i)) for i in range(3)]
    path.write_text("\n".join(s.to_json() for s in specs) + "\n\n")
    assert read_specs_jsonl(str(path)) == specs

    bad = tmp_path / "bad.jsonl"
    bad.write_text(specs[0].to_json() + "\n" + json.dumps(spec_dict(hand="both")) + "\n")
    with pytest.raises(SpecError, match=rf"{bad}:2: spec.hand must be one of .*'both'"):
        read_specs_jsonl(str(bad))

    empty = tmp_path / "empty.jsonl"
    empty.write_text("\n")
    with pytest.raises(SpecError, match="holds no spec"):
        read_specs_jsonl(str(empty))
    with pytest.raises(SpecError, match="cannot read specs file"):
        read_specs_jsonl(str(tmp_path / "missing.jsonl"))


# --- holes found by outside testing (issue 11) --------------------------------------


def test_a_motion_type_that_contradicts_the_tokens_is_refused():
    with pytest.raises(SpecError, match=r"spec.motion_type 'circular' contradicts the motion's tokens, which make it 'linear'"):
        EpisodeSpec.from_dict(spec_dict(motion_type="circular"))
    assert EpisodeSpec.from_dict(spec_dict(motion_type="custom")).motion_type == "custom"


def test_an_object_far_outside_its_size_is_refused():
    with pytest.raises(SpecError, match=r"spec.object_size of a tennis_ball must be in \[0.335, 1.340\].*got 5.0"):
        EpisodeSpec.from_dict(spec_dict(object_size=5.0))


def test_every_recipe_spec_is_valid_under_the_new_rules():
    from generators.recipe import slice_specs

    for name in ("linear-fast", "circular-medium", "harmonic-slow", "test-1k"):
        for spec in slice_specs(name, 300):
            assert EpisodeSpec.from_json(spec.to_json()) == spec


def test_a_lone_surrogate_in_the_text_is_one_clear_error():
    with pytest.raises(SpecError, match=r"spec.text is not valid Unicode text \(surrogates not allowed"):
        EpisodeSpec.from_json(json.dumps(spec_dict(text="grasp \ud800 it")))


def test_a_huge_integer_is_one_clear_error():
    line = json.dumps(spec_dict()).replace('"seed": 7', '"seed": ' + "9" * 5000)
    with pytest.raises(SpecError, match=r"spec.seed must be in \[0, 9223372036854775807\], got 9{20}\.\.\. \(an integer of 5,000 digits\)"):
        EpisodeSpec.from_json(line)


def test_a_huge_bad_value_is_echoed_short():
    with pytest.raises(SpecError) as caught:
        EpisodeSpec.from_dict(spec_dict(hand="x" * 10_000_000))
    assert len(str(caught.value)) < 400 and "10,000,002 characters" in str(caught.value)


def test_token_and_overlay_counts_are_bounded():
    token = {"type": "L", "start": [0.0, 3.0], "direction": 0.5, "speed": 0.01, "acceleration": 0.0, "duration": 0.01}
    with pytest.raises(SpecError, match="at most 256 tokens, got 20,000"):
        EpisodeSpec.from_dict(spec_dict(motion={"base": [token] * 20_000}))


BOX = {"category": "crate", "centre": [1.0, 3.0], "half_extents": [0.5, 0.4, 0.5], "yaw": 0.3}


def test_obstacles_round_trip_and_are_left_out_when_there_are_none():
    plain = EpisodeSpec.from_dict(spec_dict())
    assert "obstacles" not in json.loads(plain.to_json())
    boxed = EpisodeSpec.from_dict(spec_dict(motion_type="obstacle", obstacles=[BOX]))
    assert json.loads(boxed.to_json())["obstacles"] == [BOX]
    assert EpisodeSpec.from_json(boxed.to_json()) == boxed and boxed.spec_hash != plain.spec_hash
    assert EpisodeSpec.from_dict(spec_dict(obstacles=[BOX])).motion_type == "linear"


@pytest.mark.parametrize(
    "obstacles, message",
    [
        ("crate", r"spec.obstacles must be a list"),
        ([dict(BOX, category="tank")], r"spec.obstacles\[0\]: obstacle.category must be one of .*'tank'"),
        ([dict(BOX, centre=[40.0, 3.0])], r"obstacle.centre must lie on the table"),
        ([dict(BOX, half_extents=[0.5, 0.0, 0.5])], r"obstacle.half_extents must each be in"),
        ([dict(BOX, half_extents=[0.5, 0.5])], r"obstacle.half_extents must be a list of 3 numbers"),
        ([dict(BOX, yaw="north")], r"spec.obstacles\[0\].yaw must be a number, got 'north'"),
        ([dict(BOX, colour="red")], r"obstacle has unknown field\(s\) \['colour'\]"),
        ([{"category": "crate"}], r"obstacle is missing field\(s\) \['centre', 'half_extents'\]"),
        ([BOX] * 9, r"at most 8 obstacles, got 9"),
    ],
)
def test_bad_obstacles_name_the_entry_and_the_value(obstacles, message):
    with pytest.raises(SpecError, match=message):
        EpisodeSpec.from_dict(spec_dict(obstacles=obstacles))


def test_an_obstacle_motion_type_needs_obstacles():
    with pytest.raises(SpecError, match=r"spec.motion_type 'obstacle' contradicts"):
        EpisodeSpec.from_dict(spec_dict(motion_type="obstacle"))
