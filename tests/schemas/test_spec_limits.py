"""Spec input is bounded (schemas.limits): every out-of-bounds value, repeated key, huge
number or unreadable specs file given to ``pipeline build --specs`` is one line naming the
field (or the file), a non-zero exit, no traceback, no warning and no output written."""

from __future__ import annotations

import copy
import json
import math
import os
import re
import resource
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from pipeline.cli import main
from schemas import limits
from schemas.errors import SpecError
from schemas.motion import ArcToken, ClothoidToken, HarmonicToken, LineToken, ProjectileToken, token_from_dict
from schemas.spec import EpisodeSpec, read_specs_lines
from schemas.values import LongNumber, load_json

#: linear-fast's episode 0, as ``catalog specs`` prints it.
GOOD = {
    "episode_index": 0, "hand": "right", "intercept_setting": "fast",
    "motion": {"base": [{"acceleration": 0.12, "direction": 5.497787143782138, "duration": 1.45, "speed": 0.6,
                         "start": [-2.25, 6.0], "type": "L"}], "overlays": []},
    "motion_type": "linear", "num_frames": 29, "object": "paper_roll", "object_size": 1.265, "observe_frames": 9,
    "rollout_format": "observe-before-act", "seed": 1, "slice": "linear-fast",
    "text": "Pick up the paper roll sliding in a straight line.",
}
BIN = Path(sys.executable).parent


def _spec(**changes) -> dict:
    data = copy.deepcopy(GOOD)
    data.update(changes)
    return data


def _token(kind: str, **fields) -> dict:
    return _spec(motion_type="custom", motion={"base": [{"type": kind, **fields}]})


def _line(**fields) -> dict:
    return _spec(motion={"base": [{**GOOD["motion"]["base"][0], **fields}]})


def _build(tmp_path: Path, capsys, text: str) -> str:
    """``pipeline build --specs`` of ``text`` in this process: the one line it printed."""
    path = tmp_path / "specs.jsonl"
    path.write_text(text)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main(["build", "--specs", str(path), "--out", str(tmp_path / "out"), "--workers", "1"])
    err = capsys.readouterr().err
    assert code != 0 and not caught, (code, [str(w.message) for w in caught])
    assert err.count("\n") == 1 and "Traceback" not in err and "Warning" not in err, err
    assert not (tmp_path / "out").exists()
    return err


def _capped_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))


def _build_in_a_child(tmp_path: Path, specs: str) -> str:
    """``pipeline build --specs`` as a user runs it, in a child process whose memory and time
    are capped (the code before the limits allocated 16 GiB, read for ever, or built for hours)."""
    result = subprocess.run(
        [str(BIN / "pipeline"), "build", "--specs", specs, "--out", str(tmp_path / "out"), "--workers", "1"],
        capture_output=True, text=True, timeout=90, preexec_fn=_capped_memory,
        env={**os.environ, "PYTHONWARNINGS": "always"},
    )
    assert result.returncode != 0
    assert result.stderr.count("\n") == 1, result.stderr
    assert "Traceback" not in result.stderr and "Warning" not in result.stderr
    assert not (tmp_path / "out").exists()
    return result.stderr


CASES = {
    "C.curvature": (_token("C", curvature=1e300, curvature_slope=0.0, duration=2.0, start=[0, 4], speed=0.6),
                    r"spec\.motion\.base\[0\]\.curvature must be in \[-100, 100\], got 1e\+300"),
    "C.curvature_slope": (_token("C", curvature_slope=1e300, duration=2.0, start=[0, 4], speed=0.6),
                          r"spec\.motion\.base\[0\]\.curvature_slope must be in .*got 1e\+300"),
    "C.curvature_slope after a line": (
        _spec(motion={"base": [GOOD["motion"]["base"][0], {"type": "C", "curvature_slope": 1e300, "duration": 0.5}]}),
        r"spec\.motion\.base\[1\]\.curvature_slope must be in .*got 1e\+300"),
    "H.drift": (_token("H", centre=[0, 4], axis=0, amplitude=1, frequency=0.5, phase=0, duration=2, drift=[1e308, 0]),
                r"spec\.motion\.base\[0\]\.drift\[0\] must be in \[-100, 100\], got 1e\+308"),
    "H.amplitude": (_token("H", centre=[0, 4], axis=0, amplitude=1e308, frequency=0.5, phase=0, duration=2),
                    r"spec\.motion\.base\[0\]\.amplitude must be in \[0, 100\], got 1e\+308"),
    "L.speed": (_line(speed=1e308), r"spec\.motion\.base\[0\]\.speed must be in \[0, 100\], got 1e\+308"),
    "num_frames 2^31-1": (_spec(num_frames=2**31 - 1), r"spec\.num_frames must be <= 1200, got 2147483647"),
    "num_frames 200000": (_spec(num_frames=200_000), r"spec\.num_frames must be <= 1200, got 200000"),
    "empty motion list": (_spec(motion=[]), r"spec\.motion needs at least one token, got none"),
    "empty base track": (_spec(motion={"base": []}), r"spec\.motion\.base needs at least one token, got none"),
    "overlay past the limits": (
        _spec(motion={"base": GOOD["motion"]["base"],
                      "overlays": [{"start": 1e300, "tokens": [{"type": "H", "centre": [0, 0], "axis": 0,
                                                                "amplitude": 0.1, "frequency": 1, "phase": 0,
                                                                "duration": 1}]}]}),
        r"spec\.motion\.overlays\[0\]\.start must be in \[0, 120\], got 1e\+300"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_an_out_of_bounds_value_is_one_line_naming_its_field(case, tmp_path, capsys):
    spec, message = CASES[case]
    err = _build(tmp_path, capsys, json.dumps(spec) + "\n")
    assert err.startswith("pipeline build: error: ") and "specs.jsonl:1: " in err
    assert re.search(message, err), err


@pytest.mark.parametrize(
    "text, message",
    [
        (json.dumps(GOOD)[:-1] + ', "object": "orange"}', "spec.object is given twice"),
        (json.dumps(GOOD).replace('"speed": 0.6', '"speed": 0.6, "speed": 0.7'), r"spec.motion.base[0].speed is given twice"),
        (json.dumps(GOOD).replace('"seed": 1', '"seed": ' + "9" * 5000),
         "spec.seed must be in [0, 9223372036854775807], got 99999999999999999999... (an integer of 5,000 digits)"),
        (json.dumps(GOOD).replace('"speed": 0.6', '"speed": ' + "9" * 5000),
         "spec.motion.base[0].speed holds at most 40 digits, got 99999999999999999999... (an integer of 5,000 digits)"),
    ],
)
def test_repeated_keys_and_huge_numbers_name_their_field(text, message, tmp_path, capsys):
    assert message in _build(tmp_path, capsys, text + "\n")


def test_a_motion_long_enough_for_2_31_frames_is_refused_before_allocating(tmp_path):
    spec = _line(duration=2e8, speed=0.0, acceleration=0.0) | {"num_frames": 2**31 - 1}
    (tmp_path / "s.jsonl").write_text(json.dumps(spec) + "\n")
    err = _build_in_a_child(tmp_path, str(tmp_path / "s.jsonl"))
    assert "s.jsonl:1: spec.motion.base[0].duration must be in (0, 120], got 200000000.0" in err


def test_a_200000_frame_episode_is_refused_not_built_for_ever(tmp_path):
    spec = _line(duration=10_001.0, speed=0.0, acceleration=0.0) | {"num_frames": 200_000}
    (tmp_path / "s.jsonl").write_text(json.dumps(spec) + "\n")
    assert "s.jsonl:1: spec.motion.base[0].duration must be in (0, 120]" in _build_in_a_child(tmp_path, str(tmp_path / "s.jsonl"))


@pytest.mark.parametrize("kind", ["device", "fifo", "folder"])
def test_a_specs_file_that_is_not_a_regular_file_is_refused_unread(kind, tmp_path):
    path = {"device": "/dev/zero", "fifo": str(tmp_path / "fifo"), "folder": str(tmp_path)}[kind]
    if kind == "fifo":
        os.mkfifo(path)
    err = _build_in_a_child(tmp_path, path)
    assert f"specs file {path} is not a regular file (a " in err


def test_a_specs_file_over_the_size_cap_is_refused_unread(tmp_path):
    path = tmp_path / "huge.jsonl"
    with open(path, "wb") as handle:
        handle.truncate(limits.MAX_SPECS_FILE_BYTES + 1)  # sparse: no disk used
    err = _build_in_a_child(tmp_path, str(path))
    assert f"specs file {path} holds {limits.MAX_SPECS_FILE_BYTES + 1:,} bytes, more than the" in err


def test_a_line_over_the_cap_is_refused_by_line_number(tmp_path, capsys):
    line = json.dumps(GOOD)
    text = line + "\n" + line[:-1] + " " * limits.MAX_SPEC_LINE_BYTES + "}\n"
    assert f"specs.jsonl:2: line longer than {limits.MAX_SPEC_LINE_BYTES:,} bytes" in _build(tmp_path, capsys, text)


@pytest.mark.parametrize("field, named", [
    ("text", "its text runs past the cut (at most 10,000 characters)"),
    ("tokens", "its motion.base runs past the cut (at most 256 tokens)"),
    ("overlays", "its motion.overlays runs past the cut (at most 16 tracks)"),
])
def test_a_line_over_the_cap_names_the_field_that_made_it_long(tmp_path, capsys, field, named):
    """Before: 50 MB of text, 100,000 tokens or 100,000 overlays were refused as a long line
    without naming the field or its limit."""
    base = GOOD["motion"]["base"]
    spec = {"text": _spec(text="x" * (limits.MAX_SPEC_LINE_BYTES + 10)),
            "tokens": _spec(motion={"base": base * 100_000}),
            "overlays": _spec(motion={"base": base, "overlays": [base] * 100_000})}[field]
    assert named in _build(tmp_path, capsys, json.dumps(spec) + "\n")


# --- the limits at their boundary: the limit itself is accepted, just past it refused ---

def _past(value: float) -> float:
    return math.nextafter(value, math.inf)


H = {"type": "H", "centre": [0.0, 4.0], "axis": 0.0, "amplitude": 0.1, "frequency": 0.1, "phase": 0.0, "duration": 1.0}
L = {"type": "L", "start": [0.0, 4.0], "direction": 0.0, "speed": 1.0, "acceleration": 0.0, "duration": 1.0}
A = {"type": "A", "centre": [0.0, 4.0], "radius": 1.0, "angular_velocity": 1.0, "start_angle": 0.0, "turn": 1,
     "duration": 1.0}
C = {"type": "C", "curvature_slope": 0.0, "duration": 0.1, "speed": 0.1, "curvature": 0.0}
P = {"type": "P", "start": [0.0, 4.0], "velocity": [0.0, 1.0, 0.0], "duration": 1.0, "gravity": 98.1, "height": 0.0}


@pytest.mark.parametrize(
    "token, field, limit",
    [
        (L, "speed", limits.MAX_SPEED),
        (L, "duration", limits.MAX_SECONDS),
        (dict(L, speed=0.0, duration=0.01), "acceleration", limits.MAX_ACCELERATION),
        (dict(L, speed=0.0, duration=0.01), "acceleration", -limits.MAX_ACCELERATION),
        (L, "direction", limits.MAX_ANGLE),
        (dict(A, angular_velocity=0.5), "radius", limits.MAX_RADIUS),
        (dict(A, radius=0.01), "angular_velocity", limits.MAX_TURN_RATE),
        (H, "amplitude", limits.MAX_AMPLITUDE),
        (H, "frequency", limits.MAX_FREQUENCY),
        (H, "phase", -limits.MAX_ANGLE),
        (dict(H, amplitude=0.0, drift=[0.0, 0.0]), "drift", limits.MAX_SPEED),
        (C, "curvature", limits.MAX_CURVATURE),
        (C, "curvature_slope", -limits.MAX_CURVATURE_SLOPE),
        (P, "gravity", limits.MAX_ACCELERATION),
        (P, "height", limits.MAX_HEIGHT),
        (P, "start", limits.MAX_POSITION),
        (P, "velocity", -limits.MAX_SPEED),
    ],
)
def test_a_token_field_at_its_limit_is_accepted_and_just_past_it_refused(token, field, limit):
    def with_value(value):
        if isinstance(token[field], list):
            return dict(token, **{field: [value] + token[field][1:]})
        return dict(token, **{field: value})

    assert token_from_dict(with_value(limit))
    beyond = math.nextafter(limit, math.copysign(math.inf, limit))
    with pytest.raises(SpecError, match=rf"^{token['type']}\.{field}(\[0\])? must be "):
        token_from_dict(with_value(beyond))


def test_the_smallest_radius_is_accepted_and_a_smaller_one_refused():
    assert token_from_dict(dict(A, radius=limits.MIN_RADIUS)).radius == limits.MIN_RADIUS
    with pytest.raises(SpecError, match=r"A\.radius must be in \[0\.01, 100\]"):
        token_from_dict(dict(A, radius=math.nextafter(limits.MIN_RADIUS, 0.0)))


@pytest.mark.parametrize(
    "make, field",
    [
        (lambda v: LineToken((0.0, 4.0), 0.0, 0.0, v, 1.0), "L.acceleration"),
        (lambda v: ArcToken((0.0, 4.0), 2.0, v / 2, 0.0, 1, 1.0), "A.angular_velocity"),
        (lambda v: HarmonicToken((0.0, 4.0), 0.0, v / (2 * math.pi), 1.0, 0.0, 1.0), "H.amplitude"),
        (lambda v: HarmonicToken((0.0, 4.0), 0.0, 0.0, 1.0, 0.0, 1.0, (v * 0.6, v * 0.8)), "H.amplitude"),
    ],
)
def test_a_token_may_reach_the_speed_limit_but_not_pass_it(make, field):
    make(limits.MAX_SPEED * (1 - 1e-12))
    with pytest.raises(SpecError, match=rf"^{field} makes the object reach 100 units/s \(at most 100\)"):
        make(limits.MAX_SPEED * (1 + 1e-12))


def test_a_clothoid_turns_at_most_32_times():
    # heading change (|k0| + |c| s) s over the arc length s = speed x duration
    ClothoidToken(curvature_slope=0.0, duration=limits.MAX_TURNING / 10.0, speed=1.0, curvature=10.0)
    with pytest.raises(SpecError, match=r"C\.curvature_slope turns the heading by up to 201\.1 rad"):
        ClothoidToken(curvature_slope=0.0, duration=_past(limits.MAX_TURNING / 10.0), speed=1.0, curvature=10.0)
    ProjectileToken((0.0, 4.0), (0.0, 1.0, 0.0), 1.0)


@pytest.mark.parametrize("field", ["num_frames", "observe_frames"])
def test_frame_counts_at_the_limit_are_accepted_and_one_more_refused(field):
    long_line = {"base": [dict(L, speed=0.0, duration=limits.MAX_NUM_FRAMES / 20)]}
    if field == "num_frames":
        assert EpisodeSpec.from_dict(_spec(motion=long_line, num_frames=limits.MAX_NUM_FRAMES)).num_frames == 1200
    with pytest.raises(SpecError, match=rf"spec\.{field} must be <= 1200, got 1201"):
        EpisodeSpec.from_dict(_spec(motion=long_line, **{field: limits.MAX_NUM_FRAMES + 1}))


def test_an_overlay_ends_within_the_time_limit():
    tokens = [dict(H, duration=limits.MAX_SECONDS / 2)]
    motion = {"base": GOOD["motion"]["base"], "overlays": [{"start": limits.MAX_SECONDS / 2, "tokens": tokens}]}
    assert EpisodeSpec.from_dict(_spec(motion=motion)).motion.overlays[0].end == limits.MAX_SECONDS
    motion["overlays"][0]["start"] += 0.001
    with pytest.raises(SpecError, match=r"spec\.motion\.overlays\[0\] ends at 120\.001 s"):
        EpisodeSpec.from_dict(_spec(motion=motion))


def test_integers_of_up_to_40_digits_are_read_and_longer_ones_kept_as_text():
    assert load_json("x", "[" + "9" * 40 + ", -" + "9" * 40 + "]") == [10**40 - 1, -(10**40 - 1)]
    longer = load_json("x", "[" + "9" * 41 + "]")[0]
    assert isinstance(longer, LongNumber) and "41 digits" in repr(longer)


def test_a_repeated_key_names_its_path_at_any_depth():
    with pytest.raises(SpecError, match=r"^x\.a\[1\]\.b\.c is given twice"):
        load_json("x", '{"a": [{}, {"b": {"c": 1, "c": 2}}]}')
    assert load_json("x", '{"a": [{"c": 1}, {"c": 2}]}') == {"a": [{"c": 1}, {"c": 2}]}


def test_a_line_at_the_cap_is_read_and_a_file_at_the_cap_too(tmp_path, monkeypatch):
    line = json.dumps(GOOD)
    padded = line[:-1] + " " * (limits.MAX_SPEC_LINE_BYTES - len(line) - 1) + "}\n"
    assert len(padded.encode()) == limits.MAX_SPEC_LINE_BYTES
    path = tmp_path / "s.jsonl"
    path.write_text(padded)
    assert [n for n, _ in read_specs_lines(str(path))] == [1]
    path.write_text(line + "\n")
    monkeypatch.setattr("schemas.spec.MAX_SPECS_FILE_BYTES", len(line) + 1)
    assert len(read_specs_lines(str(path))) == 1
    path.write_text(line + "\n\n")
    with pytest.raises(SpecError, match=r"holds \d+ bytes, more than the \d+ a specs file may hold"):
        read_specs_lines(str(path))


def test_the_largest_spec_the_limits_admit_fits_on_one_line():
    number, seconds = -1.2345678901234567e-05, 0.012345678901234567
    harmonic = {"type": "H", "centre": [number, number], "axis": number, "amplitude": -number, "frequency": -number,
                "phase": number, "duration": seconds, "drift": [number, number]}
    track = [harmonic] * limits.MAX_TRACK_TOKENS
    motion = {"base": track, "overlays": [{"start": -number, "tokens": track}] * limits.MAX_OVERLAYS}
    spec = EpisodeSpec.from_dict(_spec(motion=motion, motion_type="custom", num_frames=29, text="\U0001f600" * limits.MAX_TEXT,
                                       obstacles=[{"category": "crate", "centre": [number, number],
                                                   "half_extents": [0.05, 0.05, 0.05], "yaw": number}] * 8))
    assert len(json.dumps(spec.to_dict()).encode()) < limits.MAX_SPEC_LINE_BYTES


def test_a_spec_at_the_speed_limit_is_refused_as_infeasible_not_with_a_traceback(tmp_path):
    # at 100 units/s the object passes the camera's near plane while observed: its silhouette
    # once took a 199 GiB raster (generators.visibility)
    (tmp_path / "s.jsonl").write_text(json.dumps(_line(speed=limits.MAX_SPEED, acceleration=0.0)) + "\n")
    err = _build_in_a_child(tmp_path, str(tmp_path / "s.jsonl"))
    assert "s.jsonl:1: infeasible episode linear-fast:000000: the object is only" in err


def test_a_clothoid_joined_at_speed_is_refused_by_its_turning_not_a_huge_quadrature(tmp_path):
    # its own fields pass (default speed 1); joined after a 50 units/s line it would turn
    # 250,000 rad, once a 7.7 GiB quadrature array (generators.primitives.clothoid)
    line = dict(L, speed=50.0, duration=0.5)
    spec = _spec(motion_type="custom", motion={"base": [line, {"type": "C", "curvature_slope": 100.0, "duration": 1.0}]})
    (tmp_path / "s.jsonl").write_text(json.dumps(spec) + "\n")
    err = _build_in_a_child(tmp_path, str(tmp_path / "s.jsonl"))
    assert "s.jsonl:1: episode linear-fast:000000: a C token starting at 0.500 s, joined at 50 units/s" in err
    assert "turns the heading by up to 2.5e+05 rad (at most 201.1: 32 turns)" in err
