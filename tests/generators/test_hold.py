"""The hold test (generators.hold): it holds what a hand grips, drops what it does not,
and gives the same bytes for the same inputs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from generators import hold
from generators.ground_truth import plan
from generators.hand import REST_JOINTS, SPLAYED_THUMB, mirror_palm_pose
from generators.hold import HoldResult, palm_path
from generators.hold_episode import closing_frame, episode_hold
from generators.hold_grasp import closing_angles, hover_palm, resting_pose
from generators.hold_params import (
    HOLD_SECONDS,
    LIFT_HEIGHT,
    LIFT_SECONDS,
    PENETRATION_TOLERANCE,
    SLIP_TOLERANCE,
    object_mass,
)
from generators.recipe import spec_for
from schemas.errors import SpecError
from schemas.events import grasp_closed
from schemas.objects import OBJECTS, object_category
from schemas.scene import PALM_HOVER

STILL = np.zeros(3)
ROOT = Path(__file__).resolve().parents[2]


def hold_test(*args, **kwargs):
    """:func:`generators.hold.hold_test` of the splayed hand, whose grasps
    :mod:`generators.hold_grasp` makes (the hand-made grips below)."""
    return hold.hold_test(*args, geometry=SPLAYED_THUMB, **kwargs)


def _grip(name: str, side: str = "right", offset=(0.2, -0.23, -0.3)):
    """A palm resting on the object, shifted back and away from the thumb, fingers closed on it."""
    size = object_category(name).nominal_size
    palm = hover_palm(name, size, (offset[0] if side == "right" else -offset[0], offset[1], offset[2]))
    return name, size, side, palm, STILL, closing_angles(name, size, side, palm), resting_pose(name, size), STILL, STILL


@pytest.mark.parametrize("name", ["tennis_ball", "baseball", "orange"])
def test_a_sphere_gripped_under_the_palm_is_held(name):
    result = hold_test(*_grip(name))
    assert result.held and result.slip < 0.2, result
    assert result.rise > LIFT_HEIGHT - 0.3 and result.contacts >= 2


def test_an_open_hand_or_a_fist_beside_the_object_holds_nothing():
    name, size, side, palm, _, joints, pose, _, _ = _grip("tennis_ball")
    opened = hold_test(name, size, side, palm, STILL, REST_JOINTS, pose, STILL, STILL)
    beside = hold_test(name, size, side, palm + np.array([1.2, 0, 0, 0, 0, 0]), STILL, joints, pose, STILL, STILL)
    for result in (opened, beside):
        assert not result.held and result.slip > SLIP_TOLERANCE and abs(result.rise) < 0.1, result


def test_a_hand_that_starts_inside_the_object_holds_nothing():
    name, size, side, palm, _, joints, pose, _, _ = _grip("mug", offset=(0.0, 0.0, 0.0))
    sunk = palm - np.array([0, PALM_HOVER + 0.3, 0, 0, 0, 0])  # the palm 0.18 below the mug's top
    result = hold_test(name, size, side, sunk, STILL, joints, pose, STILL, STILL)
    assert result.penetration > PENETRATION_TOLERANCE and not result.held
    assert hold_test(*_grip("baseball")).penetration <= PENETRATION_TOLERANCE


def test_same_inputs_same_bytes_whatever_ran_before():
    hold.MEMO.clear()
    a = hold_test(*_grip("baseball"))
    b = hold_test(*_grip("soda_can", offset=(0.0, 0.0, 0.0)))
    hold.MEMO.clear()  # simulated again, after another object's test, not remembered
    again = hold_test(*_grip("baseball"))
    assert a == again and a != b and again is not a
    assert np.float64(a.slip).tobytes() == np.float64(again.slip).tobytes()


def test_a_test_run_again_on_the_same_inputs_is_remembered_not_simulated(monkeypatch):
    """Scoring a run again (another reading, a chance row) must not pay the physics twice."""
    first = hold_test(*_grip("orange"))
    monkeypatch.setattr(hold.p, "stepSimulation", lambda **kw: (_ for _ in ()).throw(AssertionError("simulated")))
    assert hold_test(*_grip("orange")) is first
    with pytest.raises(AssertionError, match="simulated"):
        hold_test(*_grip("orange", offset=(0.21, -0.23, -0.3)))  # another input is simulated


def test_another_process_gives_the_same_bytes():
    code = ("import sys; sys.path.insert(0, 'tests/generators'); from test_hold import _grip; "
            "from test_hold import hold_test; r = hold_test(*_grip('baseball')); print(r.slip.hex(), r.rise.hex())")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, cwd=ROOT).stdout.split()
    here = hold_test(*_grip("baseball"))
    assert out == [here.slip.hex(), here.rise.hex()]


def test_the_physics_client_without_its_renderer_gives_the_same_bytes(monkeypatch):
    """The hold test's client unloads pybullet's TinyRenderer (no visual shapes made for its
    bodies, most of a test's set-up); a client that keeps it must give the same result."""
    lean = hold.hold_test(*_grip("soda_can", offset=(0.0, 0.0, 0.0)))
    full = hold.p.connect(hold.p.DIRECT)
    try:
        assert hold.p.getNumBodies(physicsClientId=full) == 0
        monkeypatch.setattr(hold, "_client", lambda: full)
        hold.MEMO.clear()
        kept = hold.hold_test(*_grip("soda_can", offset=(0.0, 0.0, 0.0)))
    finally:
        hold.p.disconnect(physicsClientId=full)
    assert kept == lean and kept is not lean
    assert np.float64(kept.slip).tobytes() == np.float64(lean.slip).tobytes()


def test_the_left_hand_mirrors_the_right():
    right = hold_test(*_grip("orange", "right"))
    left = hold_test(*_grip("orange", "left"))
    assert right.held == left.held and abs(right.slip - left.slip) < 1e-3


def test_the_palm_path_lifts_and_glides_to_rest():
    t = np.linspace(0.0, LIFT_SECONDS + HOLD_SECONDS, 121)
    path = palm_path(np.array([1.0, 2.0, 3.0]), np.array([2.0, 5.0, -1.0]), t)
    assert np.allclose(path[0], [1.0, 2.0, 3.0])
    end = [1.0 + LIFT_SECONDS, 2.0 + LIFT_HEIGHT, 3.0 - LIFT_SECONDS / 2.0]  # v * T / 2 horizontally
    assert np.allclose(path[t >= LIFT_SECONDS], end)
    assert np.all(np.diff(path[:, 1]) >= 0.0)


def test_episode_hold_starts_at_the_first_closed_frame():
    spec = spec_for("test-1k", 0)
    hp, _, _ = plan(spec)
    frame, result = episode_hold(spec, hp.palm_pose, hp.joint_angles)
    assert frame == int(np.argmax(grasp_closed(hp.joint_angles, hp.grasp_angles)))
    assert isinstance(result, HoldResult)
    assert closing_frame(hp.joint_angles[:frame], hp.grasp_angles) is None
    assert episode_hold(spec, hp.palm_pose, np.zeros_like(hp.joint_angles)) is None


def test_mass_scales_with_volume_and_every_object_has_a_material():
    for name, cat in OBJECTS.items():
        assert object_mass(name, 2.0 * cat.nominal_size) == pytest.approx(8.0 * object_mass(name, cat.nominal_size))
        assert 0.02 < object_mass(name, cat.nominal_size) < 1.0


@pytest.mark.parametrize(
    "change, words",
    [
        ({"palm_pose": np.zeros(5)}, "palm_pose must be 6"),
        ({"joint_angles": np.full(15, np.nan)}, "joint_angles must be 15"),
        ({"object_size": 50.0}, "object size"),
        ({"side": "middle"}, "hand side"),
        ({"object_name": "anvil"}, "unknown object"),
    ],
)
def test_bad_input_is_one_clear_error(change, words):
    keys = ("object_name", "object_size", "side", "palm_pose", "palm_velocity", "joint_angles", "object_pose",
            "object_velocity", "object_angular_velocity")
    kwargs = dict(zip(keys, _grip("tennis_ball"), strict=True)) | change
    with pytest.raises(SpecError, match=words):
        hold_test(**kwargs)


def test_mirror_helper_is_what_the_left_grip_uses():
    right = _grip("orange", "right")[3]
    assert np.allclose(mirror_palm_pose(right), _grip("orange", "left")[3])
