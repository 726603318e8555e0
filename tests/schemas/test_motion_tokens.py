"""Motion tokens and motions: JSON round trips and validation messages."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.errors import SpecError
from schemas.limits import MAX_ANGLE, MAX_SPEED
from schemas.motion import (
    TOKEN_TYPES,
    ArcToken,
    ClothoidToken,
    HarmonicToken,
    LineToken,
    Motion,
    ProjectileToken,
    Track,
    token_from_dict,
    token_to_dict,
)

TOKENS = [
    LineToken((0.5, 3.0), 0.3, 1.2, -0.25, 4.0),
    ArcToken((0.0, 4.0), 1.5, 1.2, 0.3, -1, 4.0),
    HarmonicToken((0.0, 4.0), 0.7, 1.0, 0.8, 0.2, 4.0),
    HarmonicToken((0.0, 4.0), 0.7, 1.0, 0.8, 0.2, 4.0, (0.3, -0.1)),
    ClothoidToken(0.5, 2.0),
    ClothoidToken(-0.5, 2.0, (1.0, 2.0), 0.4, 1.5, 0.25),
    ProjectileToken((0.0, 3.0), (1.0, 6.0, 0.5), 2.0, height=1.5, restitution=0.7),
]

GOOD = {
    "L": {"type": "L", "start": [0.0, 3.0], "direction": 0.5, "speed": 1.0, "acceleration": 0.0, "duration": 2.0},
    "A": {"type": "A", "centre": [0.0, 4.0], "radius": 1.5, "angular_velocity": 1.0, "start_angle": 0.0, "turn": 1, "duration": 2.0},
    "H": {"type": "H", "centre": [0.0, 4.0], "axis": 0.0, "amplitude": 1.0, "frequency": 0.5, "phase": 0.0, "duration": 2.0},
    "C": {"type": "C", "curvature_slope": 0.3, "duration": 2.0},
    "P": {"type": "P", "start": [0.0, 3.0], "velocity": [1.0, 5.0, 0.0], "duration": 2.0},
}


def with_(kind: str, **changes):
    out = dict(GOOD[kind])
    out.update(changes)
    return out


@pytest.mark.parametrize("token", TOKENS, ids=lambda t: t.type)
def test_token_round_trips_through_json(token):
    data = token_to_dict(token)
    assert next(iter(data)) == "type"
    back = token_from_dict(json.loads(json.dumps(data)))
    assert back == token and type(back) is type(token)
    assert token_to_dict(back) == data


def test_every_token_type_has_a_good_example():
    assert sorted(GOOD) == sorted(TOKEN_TYPES)
    for data in GOOD.values():
        assert token_to_dict(token_from_dict(data))["type"] == data["type"]


def test_motion_round_trips_through_json():
    m = Motion(Track(tuple(TOKENS[:3])), (Track((TOKENS[3],), 1.5), Track((TOKENS[4], TOKENS[5]), 0.0)))
    text = m.to_json()
    back = Motion.from_json(text)
    assert back == m
    assert back.to_json() == text
    assert json.loads(text)["overlays"][0]["start"] == 1.5
    assert m.token_types == "LAH"
    assert math.isclose(m.duration, 12.0)


def test_motion_accepts_a_bare_token_list():
    assert Motion.from_dict([GOOD["L"], GOOD["C"]]) == Motion.of(token_from_dict(GOOD["L"]), token_from_dict(GOOD["C"]))


@settings(max_examples=60, deadline=None)
@given(
    st.floats(min_value=-MAX_ANGLE, max_value=MAX_ANGLE),
    st.floats(min_value=1e-9, max_value=1.0),
    st.floats(min_value=0.0, max_value=MAX_SPEED / 2),
)
def test_any_line_within_the_limits_round_trips_exactly(x, duration, speed):
    token = LineToken((x, -x), x, speed, x, duration)
    assert Motion.from_json(Motion.of(token).to_json()) == Motion.of(token)


def test_unknown_token_type_is_named():
    with pytest.raises(SpecError, match=r"unknown token type 'Q'"):
        token_from_dict({"type": "Q", "duration": 1.0})
    with pytest.raises(SpecError, match=r"missing field 'type'"):
        token_from_dict({"duration": 1.0})
    with pytest.raises(SpecError, match=r"token must be an object, got 3"):
        token_from_dict(3)


@pytest.mark.parametrize(
    "data, field, value",
    [
        (with_("A", radius=-1.0), "A.radius", "-1.0"),
        (with_("A", radius=0.0), "A.radius", "0.0"),
        (with_("L", duration=0.0), "L.duration", "0.0"),
        (with_("H", duration=-2.0), "H.duration", "-2.0"),
        (with_("C", duration=0), "C.duration", "0.0"),
        (with_("L", speed=-1.0), "L.speed", "-1.0"),
        (with_("A", angular_velocity=-0.5), "A.angular_velocity", "-0.5"),
        (with_("H", frequency=0.0), "H.frequency", "0.0"),
        (with_("H", amplitude=-0.1), "H.amplitude", "-0.1"),
        (with_("A", turn=0), "A.turn", "0"),
        (with_("A", turn=True), "A.turn", "True"),
        (with_("L", direction="east"), "L.direction", "'east'"),
        (with_("L", start=[0.0]), "L.start", r"\[0.0\]"),
        (with_("L", start=[0.0, "x"]), r"L.start\[1\]", "'x'"),
        (with_("C", speed=True), "C.speed", "True"),
        (with_("P", velocity=[1.0, 2.0]), "P.velocity", r"\[1.0, 2.0\]"),
        (with_("P", gravity=0.0), "P.gravity", "0.0"),
        (with_("P", height=-0.5), "P.height", "-0.5"),
        (with_("P", restitution=1.0), "P.restitution", "1.0"),
    ],
)
def test_bad_values_name_the_field_and_the_value(data, field, value):
    with pytest.raises(SpecError, match=rf"{field} .*{value}"):
        token_from_dict(data)


@pytest.mark.parametrize("kind", sorted(GOOD))
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_numbers_are_rejected_everywhere(kind, bad):
    numeric = [k for k, v in GOOD[kind].items() if isinstance(v, float)]
    for name in numeric:
        with pytest.raises(SpecError, match=rf"{kind}\.{name} must be finite, got {bad!r}"):
            token_from_dict(with_(kind, **{name: bad}))
    pairs = [k for k, v in GOOD[kind].items() if isinstance(v, list)]
    for name in pairs:
        with pytest.raises(SpecError, match=rf"{kind}\.{name}\[1\] must be finite, got {bad!r}"):
            value = [0.0] * len(GOOD[kind][name])
            value[1] = bad
            token_from_dict(with_(kind, **{name: value}))


@pytest.mark.parametrize("literal, shown", [("NaN", "nan"), ("Infinity", "inf"), ("-Infinity", "-inf")])
def test_non_finite_numbers_in_json_text_are_rejected(literal, shown):
    text = json.dumps({"base": [GOOD["L"]]}).replace('"speed": 1.0', f'"speed": {literal}')
    assert literal in text
    with pytest.raises(SpecError, match=rf"motion\.base\[0\]\.speed must be finite, got {shown}"):
        Motion.from_json(text)
    overlay = json.dumps({"base": [GOOD["L"]], "overlays": [{"start": 0.5, "tokens": [GOOD["H"]]}]})
    with pytest.raises(SpecError, match=rf"motion\.overlays\[0\]\.start must be finite, got {shown}"):
        Motion.from_json(overlay.replace('"start": 0.5', f'"start": {literal}'))


@pytest.mark.parametrize("kind", sorted(GOOD))
def test_missing_field_is_named(kind):
    required = [k for k in GOOD[kind] if k != "type"]
    for name in required:
        data = {k: v for k, v in GOOD[kind].items() if k != name}
        with pytest.raises(SpecError, match=rf"token \({kind}\) is missing field\(s\) \['{name}'\]"):
            token_from_dict(data)


def test_unknown_fields_are_named():
    with pytest.raises(SpecError, match=r"token \(L\) has unknown field\(s\) \['colour'\]"):
        token_from_dict(with_("L", colour="red"))
    with pytest.raises(SpecError, match=r"motion has unknown field\(s\) \['speed'\]"):
        Motion.from_dict({"base": [GOOD["L"]], "speed": 1.0})
    with pytest.raises(SpecError, match=r"motion.overlays\[0\] has unknown field\(s\) \['end'\]"):
        Motion.from_dict({"base": [GOOD["L"]], "overlays": [{"start": 0.0, "end": 1.0, "tokens": [GOOD["H"]]}]})


def test_malformed_motions_are_named():
    cases = [
        ({"overlays": []}, r"missing field 'base'"),
        ({"base": GOOD["L"]}, r"motion.base must be a list of tokens"),
        ({"base": []}, r"motion.base needs at least one token, got none"),
        ({"base": [GOOD["L"]], "overlays": {"tokens": []}}, r"motion.overlays must be a list of tracks, got \{'tokens': \[\]\}"),
        ({"base": [GOOD["L"]], "overlays": None}, r"motion.overlays must be a list of tracks, got None"),
        ({"base": [GOOD["L"]], "overlays": [[GOOD["H"]]]}, r"motion.overlays\[0\] must be an object with 'tokens'"),
        ({"base": [GOOD["L"]], "overlays": [{"tokens": 5}]}, r"motion.overlays\[0\].tokens must be a list of tokens, got 5"),
        ({"base": [GOOD["L"]], "overlays": [{"start": -1.0, "tokens": [GOOD["H"]]}]}, r"motion.overlays\[0\].start must be in \[0, 120\], got -1.0"),
        ("L", r"motion must be an object with 'base', got 'L'"),
    ]
    for data, message in cases:
        with pytest.raises(SpecError, match=message):
            Motion.from_dict(data)
    with pytest.raises(SpecError, match="not valid JSON"):
        Motion.from_json('{"base": [')


def test_constructors_validate_too():
    with pytest.raises(SpecError, match=r"motion.base must start at 0, got start=1.0"):
        Motion(Track((TOKENS[0],), 1.0))
    with pytest.raises(SpecError, match="track holds something that is not a motion token: 'L'"):
        Track(("L",))
    with pytest.raises(SpecError, match=r"motion.overlays\[0\] must be a Track"):
        Motion(Track((TOKENS[0],)), (TOKENS[1],))
    assert LineToken([1, 2], 0, 1, 0, 1).start == (1.0, 2.0)
    assert isinstance(ArcToken((0, 0), 1, 1, 0, -1.0, 1).turn, int)


def test_projectile_tokens_belong_to_the_base_track():
    flight = ProjectileToken((0.0, 3.0), (0.0, 4.0, 1.0), 1.0)
    assert Motion.of(flight).airborne and not Motion.of(TOKENS[0]).airborne
    with pytest.raises(SpecError, match=r"only be in the base track"):
        Motion(Track((TOKENS[0],)), (Track((flight,)),))
