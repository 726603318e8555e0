"""Hand geometries and grasp designs: the dataset's stay the default, the opposable thumb's
design grasps lying cylinders as they lie, keeps the fingers off the table and holds."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from generators.contact import signed_distance_local
from generators.grasp import (
    DEFAULT_DESIGN,
    DESIGNS,
    OPPOSED,
    OPPOSED_WRIST,
    SPLAYED,
    GraspDesign,
    cylinder_yaw,
    grasp_angles,
    grasp_hover,
    lowest_fingertip_offset,
)
from generators.ground_truth import episode_grasp, grasp_frame, plan
from generators.hand import (
    DEFAULT_GEOMETRY,
    FINGER_RADII,
    GEOMETRIES,
    OPPOSED_THUMB,
    SPLAYED_THUMB,
    HandGeometry,
    chain_frames,
    forward_kinematics,
    hand_geometry,
    root_rotations,
)
from generators.hold_episode import episode_hold
from generators.recipe import spec_for
from schemas.errors import SpecError
from schemas.objects import OBJECTS, object_category
from schemas.rotations import qaxis, qmul

LYING = sorted(n for n, c in OBJECTS.items() if c.lying)


def test_the_defaults_are_the_datasets_hand_and_grasp():
    assert DEFAULT_GEOMETRY is OPPOSED_THUMB and DEFAULT_DESIGN is OPPOSED_WRIST and OPPOSED_WRIST.hand is OPPOSED_THUMB
    assert SPLAYED.hand is SPLAYED_THUMB  # the hand of datasets up to 4.x
    assert hand_geometry("opposed-thumb") is OPPOSED_THUMB and set(GEOMETRIES) == {"splayed-thumb", "opposed-thumb"}
    rng = np.random.default_rng(3)
    palm, q = rng.normal(size=(4, 6)), rng.uniform(0.0, 1.0, size=(4, 15))
    for side in ("right", "left"):
        for a, b in zip(forward_kinematics(palm, q, side), forward_kinematics(palm, q, side, OPPOSED_THUMB)):
            assert np.array_equal(a, b)
    for name in OBJECTS:
        size = OBJECTS[name].nominal_size
        assert np.array_equal(grasp_angles(name, size, "right"), grasp_angles(name, size, "right", OPPOSED_WRIST, 0.0))


def test_the_opposable_thumb_points_back_and_curls_down_and_forward():
    thumb = root_rotations("right", OPPOSED_THUMB)[0]
    np.testing.assert_allclose(thumb[:, 2], [0.0, 0.0, -1.0], atol=1e-12)
    tip = chain_frames(np.zeros(6), np.r_[1.2, 0.8, 1.0, np.zeros(12)], "right", OPPOSED_THUMB)[0][0, 0, 3]
    root = np.array(OPPOSED_THUMB.roots[0])
    assert tip[1] < root[1] - 0.5 and tip[2] > root[2] - 0.5  # below the palm, curled back toward the fingers
    left = root_rotations("left", OPPOSED_THUMB)[0]
    np.testing.assert_allclose(left, np.diag([-1.0, 1.0, 1.0]) @ thumb @ np.diag([-1.0, 1.0, 1.0]))


@pytest.mark.parametrize(("change", "words"), [
    ({"roots": ((0.0, 0.0, 0.0),) * 4}, "roots must be 5"),
    ({"roots": ((0.0, 0.0, math.nan),) * 5}, "roots must be 5 finite"),
    ({"directions": (None,) * 4}, "directions must be 5"),
    ({"directions": (((0.0, 0.0, 1.0), (0.0, 0.0, 2.0)),) + (None,) * 4}, "non-parallel"),
])
def test_a_bad_hand_geometry_is_one_clear_error(change, words):
    with pytest.raises(SpecError, match=words):
        dataclasses.replace(OPPOSED_THUMB, **change)


@pytest.mark.parametrize(("change", "words"), [
    ({"hover": 0.0}, "hover must be a number in"),
    ({"hover_by_object": (("mug", True),)}, "hover must be a number in"),
    ({"low_objects": ("anvil",)}, "unknown object"),
    ({"synergy_end": (9.0,) * 15}, "synergy_end must be 15 angles"),
    ({"table_clearance": 1.0}, "table_clearance must be in"),
    ({"hand": "opposed-thumb"}, "hand must be a HandGeometry"),
])
def test_a_bad_grasp_design_is_one_clear_error(change, words):
    with pytest.raises(SpecError, match=words):
        dataclasses.replace(OPPOSED, **change)
    with pytest.raises(SpecError, match="must be a GraspDesign"):
        grasp_angles("mug", 0.8, "right", "opposed")  # type: ignore[arg-type]


def test_cylinder_yaw_reads_the_axis_turn_about_the_vertical():
    for angle in (-2.0, -0.4, 0.0, 0.7, 1.5):  # as generators.rolling turns and rolls a lying cylinder
        quat = qmul(qaxis(1, np.array([angle])), qaxis(0, np.array([1.3])))[0]
        assert math.isclose(cylinder_yaw(quat), angle, abs_tol=1e-9)


@pytest.mark.parametrize("name", LYING)
def test_a_lying_cylinder_is_sized_as_it_lies(name):
    """Sized for its axis along Z, the fingers touch the cylinder placed so without entering it;
    sized for the canonical axis (along X), they would start inside it."""
    cat, size = object_category(name), OBJECTS[name].nominal_size
    design = dataclasses.replace(OPPOSED, low_objects=(), turn_to_axis=False)
    turned = grasp_angles(name, size, "right", design, math.pi / 2)
    canonical = grasp_angles(name, size, "right", design, 0.0)
    assert not np.allclose(turned, canonical)
    palm = np.array([0.0, 2.0 * cat.half_height(size) + design.hover, 0.0, 0.0, 0.0, 0.0])
    centre = np.array([0.0, cat.half_height(size), 0.0])

    def deepest(q):
        pos = chain_frames(palm, q, "right", design.hand)[0][0]
        w = np.linspace(0.0, 1.0, 8)[:, None, None, None]
        points = (pos[:, :3][None] + w * (pos[:, 1:] - pos[:, :3])[None]) - centre  # (8, 5, 3, 3)
        local = np.stack([-points[..., 2], points[..., 1], points[..., 0]], axis=-1)  # its frame: axis along Z
        return float((signed_distance_local(local, cat.shape, cat.scaled_dims(size), 0) - FINGER_RADII[:, None]).min())

    assert deepest(turned) > -0.02
    assert deepest(canonical) < -0.05


@pytest.mark.parametrize("name", LYING)
@pytest.mark.parametrize("factor", [0.85, 1.15])
def test_a_low_grasp_keeps_the_fingers_off_the_table(name, factor):
    cat = object_category(name)
    size = cat.nominal_size * factor
    hover = grasp_hover(name, size, "right", OPPOSED)
    assert OPPOSED.min_hover <= hover <= OPPOSED.max_hover
    top = 2.0 * cat.half_height(size)
    assert top + hover + lowest_fingertip_offset(name, size, "right", OPPOSED) >= 0.0
    q = np.linspace(0.0, 1.0, 21)[:, None] * grasp_angles(name, size, "right", OPPOSED)
    pos = chain_frames(np.tile([0.0, top + hover, 0.0, 0.0, 0.0, 0.0], (21, 1)), q, "right", OPPOSED.hand)[0]
    assert (pos[..., 1] - FINGER_RADII[None, :, None]).min() >= OPPOSED.table_clearance - 1e-9


def test_the_opposed_plan_turns_the_palm_across_a_lying_cylinder_and_its_grasp_is_reproducible():
    """Turned once, on the approach: at rest before acting, constant from the intercept frame on."""
    spec = spec_for("test-1k", 5)  # a water bottle on a circle: its axis turns through the grasp
    assert spec.object in LYING
    hand, poses, _ = plan(spec, OPPOSED)
    k = grasp_frame(spec)  # where the hold test starts
    assert k == spec.intercept_frame + 4
    palm_x = np.array([math.cos(hand.palm_pose[k, 4]), -math.sin(hand.palm_pose[k, 4])])  # its X axis in (x, z)
    yaw = cylinder_yaw(poses[k, 3:])
    assert abs(palm_x @ np.array([math.cos(yaw), -math.sin(yaw)])) == pytest.approx(1.0, abs=1e-9)
    assert np.all(hand.palm_pose[: spec.observe_frames + 1, 3:] == 0.0)
    assert np.all(hand.palm_pose[spec.intercept_frame :, 4] == hand.palm_pose[k, 4])
    assert np.array_equal(episode_grasp(spec, OPPOSED), hand.grasp_angles)


@pytest.mark.parametrize("index", [0, 1, 3, 4, 7])
def test_the_opposed_ground_truth_holds_where_the_splayed_one_does_not(index):
    spec = spec_for("test-1k", index)
    for design, held in ((OPPOSED, True), (SPLAYED, False)):
        hand = plan(spec, design)[0]
        out = episode_hold(spec, hand.palm_pose, hand.joint_angles, design)
        assert out is not None and out[1].held is held, (spec.object, design.name, out)


def test_designs_are_registered_by_name():
    assert set(DESIGNS) == {"splayed", "opposed", "opposed-fixed", "opposed-wrist"} and DESIGNS["opposed"] is OPPOSED
    assert DESIGNS["opposed-fixed"].hand is OPPOSED_THUMB and not DESIGNS["opposed-fixed"].turn_to_axis
    assert all(isinstance(d, GraspDesign) and isinstance(d.hand, HandGeometry) for d in DESIGNS.values())


@pytest.mark.parametrize("side", ["right", "left"])
def test_the_hold_tests_body_is_the_opposed_hand(side):
    """The hold test's multibody of the opposed hand, palm turned, matches its forward kinematics."""
    from generators.bullet import p
    from generators.hold import _hand_body

    palm = np.array([0.3, 1.2, 0.4, 0.0, 0.7, 0.0])
    q = np.random.default_rng(5).uniform(0.0, 1.0, 15)
    client = p.connect(p.DIRECT)
    try:
        body = _hand_body(client, side, palm, q, OPPOSED_THUMB)
        links = np.array([p.getLinkState(body, j, computeForwardKinematics=True, physicsClientId=client)[4]
                          for j in range(15)])
    finally:
        p.disconnect(client)
    expected = chain_frames(palm, q, side, OPPOSED_THUMB)[0][0, :, :3].reshape(15, 3)
    np.testing.assert_allclose(links, expected, atol=1e-6)
