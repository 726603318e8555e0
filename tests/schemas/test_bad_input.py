"""Malformed input reaches the user as a SpecError naming the thing, never as a
TypeError, OverflowError, UnicodeDecodeError or RecursionError."""

import json

import numpy as np
import pytest

from schemas.errors import SpecError
from schemas.motion import LineToken, Motion, Track, token_from_dict
from schemas.objects import object_category
from schemas.spec import EpisodeSpec, read_specs_jsonl

LINE = {"type": "L", "start": [0.0, 2.0], "direction": 0.0, "speed": 1.0, "acceleration": 0.0, "duration": 3.0}


def _spec_dict(**changes):
    data = {
        "slice": "custom", "episode_index": 0, "seed": 1, "motion_type": "linear",
        "motion": {"base": [LINE]}, "object": "orange", "object_size": 0.8, "hand": "right",
        "rollout_format": "direct-act", "intercept_setting": "fast", "observe_frames": 0,
        "num_frames": 20, "text": "Grasp the orange.",
    }
    data.update(changes)
    return data


@pytest.mark.parametrize("field", ["episode_index", "seed"])
def test_integers_beyond_the_int64_columns_are_rejected(field):
    with pytest.raises(SpecError, match=field):
        EpisodeSpec.from_dict(_spec_dict(**{field: 2**63}))
    with pytest.raises(SpecError, match=field):
        EpisodeSpec.from_dict(_spec_dict(**{field: 1e300}))
    assert getattr(EpisodeSpec.from_dict(_spec_dict(**{field: 2**63 - 1})), field) == 2**63 - 1


def test_frame_counts_beyond_the_int32_columns_are_rejected():
    with pytest.raises(SpecError, match="observe_frames"):
        EpisodeSpec.from_dict(_spec_dict(rollout_format="observe-before-act", observe_frames=2**31))


def test_huge_integer_token_fields_are_spec_errors():
    with pytest.raises(SpecError, match=r"L\.start\[0\]"):
        LineToken((10**400, 0.0), 0.0, 1.0, 0.0, 1.0)


def test_numpy_scalars_are_numbers():
    token = LineToken((np.float32(0.5), np.int64(2)), np.float64(0.0), np.float32(1.0), 0, 1)
    assert token.start == (0.5, 2.0) and type(token.start[0]) is float and type(token.speed) is float
    spec = EpisodeSpec.from_dict(_spec_dict(episode_index=np.int64(7), object_size=np.float32(0.75)))
    assert spec.episode_index == 7 and type(spec.episode_index) is int
    assert spec.object_size == 0.75 and type(spec.object_size) is float
    assert spec.spec_hash == EpisodeSpec.from_dict(_spec_dict(episode_index=7, object_size=0.75)).spec_hash


def test_unhashable_object_name_is_a_spec_error():
    with pytest.raises(SpecError, match="unknown object"):
        object_category(["orange"])


def test_non_string_keys_are_spec_errors():
    with pytest.raises(SpecError, match="unknown field"):
        token_from_dict({**LINE, 1: 2, "colour": 3})
    with pytest.raises(SpecError, match="unknown field"):
        Motion.from_dict({"base": [LINE], 3: [], "extra": 1})


def test_overlays_must_be_a_sequence():
    with pytest.raises(SpecError, match="overlays"):
        Motion(Track((LineToken((0, 2), 0, 1, 0, 3),)), None)


@pytest.mark.parametrize("text", [None, 42, "[" * 100_000])
def test_from_json_rejects_non_text_and_deep_nesting(text):
    with pytest.raises(SpecError):
        EpisodeSpec.from_json(text)
    with pytest.raises(SpecError):
        Motion.from_json(text)


def test_read_specs_jsonl_names_the_line_of_bad_bytes(tmp_path):
    path = tmp_path / "specs.jsonl"
    good = json.dumps(_spec_dict()).encode()
    path.write_bytes(good + b"\n\xff\xfe garbage\n")
    with pytest.raises(SpecError, match=r"specs\.jsonl:2: not UTF-8"):
        read_specs_jsonl(str(path))
    path.write_bytes(good + b"\r\n" + good + b"\n")
    assert len(read_specs_jsonl(str(path))) == 2


def test_read_specs_jsonl_rejects_deep_nesting_and_bad_paths(tmp_path):
    path = tmp_path / "deep.jsonl"
    path.write_text("[" * 100_000 + "\n")
    with pytest.raises(SpecError, match=r"deep\.jsonl:1"):
        read_specs_jsonl(str(path))
    with pytest.raises(SpecError, match="cannot read"):
        read_specs_jsonl(None)


def _frames(n=3, **changes):
    from schemas.frames import EpisodeFrames
    from schemas.tables import ARRAY_WIDTHS

    data = {name: np.zeros((n, width), np.float32) for name, width in ARRAY_WIDTHS.items()}
    data.update(phase=np.zeros(n, np.int8), fingertip_distance=np.zeros(n, np.float32),
                palm_distance=np.zeros(n, np.float32), grasp_angles=np.zeros(15, np.float32))
    data.update(changes)
    return EpisodeFrames(**data)


@pytest.mark.parametrize(
    "changes, needle",
    [
        ({"object_pose": [[0.0] * 7] * 3}, "object_pose must be a numpy array"),
        ({"grasp_angles": None}, "grasp_angles must be a numpy array"),
        ({"phase": np.array([0.0, 0.5, 1.0])}, "phase must be a 1-D integer array"),
        ({"phase": np.zeros((3, 1), np.int8)}, "phase must be a 1-D integer array"),
    ],
)
def test_episode_frames_reject_non_arrays_and_fractional_phases(changes, needle):
    assert _frames().num_frames == 3
    with pytest.raises(SpecError, match=needle):
        _frames(**changes)


def test_a_peers_text_reaches_the_terminal_as_printable_escapes():
    """An error carrying a server's or policy's text (ESC[2J, newlines) prints as one safe line."""
    from schemas.cli import one_line
    from schemas.errors import PolicyError
    from schemas.names import printable

    line = one_line(PolicyError("server error: \x1b[2J\x1b[31mboom\nsecond line"))
    assert "\x1b" not in line and "\n" not in line and "\\x1b[2J" in line
    assert printable("a\x1b[2J\nb") == "a\\x1b[2J\\nb"
    assert printable("\x07" * 5000, 40).endswith("(5,000 characters)") and len(printable("x" * 5000, 40)) < 70
