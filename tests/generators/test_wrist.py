"""The wrist reflex (generators.wrist): the palm turns toward a lying cylinder's axis only
while the fingers close over it, within a rate and a quarter turn, deterministically; the
opposed-wrist ground truth turns by it and holds."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from generators.grasp import DESIGNS, OPPOSED_WRIST, cylinder_yaw
from generators.ground_truth import grasp_frame, plan
from generators.hold_episode import episode_hold
from generators.recipe import spec_for
from generators.wrist import (
    CLOSING_FRACTION,
    QUARTER_TURN,
    REACH,
    WRIST_MAX_SPEED,
    axis_target,
    closing_fraction,
    wrist_headings,
    wrist_step,
)
from schemas.errors import SpecError
from schemas.objects import OBJECTS
from schemas.rotations import qaxis, qmul
from schemas.versions import FPS

FIST = np.asarray(OPPOSED_WRIST.synergy_end)
STEP = WRIST_MAX_SPEED / FPS


def lying_pose(yaw: float, x: float = 0.5, z: float = 4.0) -> np.ndarray:
    """A lying cylinder's pose at (x, z) with its axis turned ``yaw`` about the vertical."""
    quat = qmul(qaxis(1, np.array([yaw])), qaxis(0, np.array([0.4])))[0]
    return np.r_[x, 0.33, z, quat]


CLOSING = 0.2 * FIST  # 20% of the way to the fist
PALM = np.array([0.5, 1.0, 4.0])  # right over the cylinder's centre


def test_closing_fraction_is_the_most_closed_joint():
    assert closing_fraction(np.zeros(15), FIST) == 0.0
    q = np.zeros(15)
    q[7] = 0.5 * FIST[7]
    assert closing_fraction(q, FIST) == pytest.approx(0.5)
    with pytest.raises(SpecError, match="15 joint angles"):
        closing_fraction(np.zeros(14), FIST)


def test_the_palm_turns_toward_the_axis_while_closing_over_a_lying_cylinder():
    pose = lying_pose(1.0)
    assert cylinder_yaw(pose[3:]) == pytest.approx(1.0)
    heading = wrist_step(0.0, PALM, CLOSING, pose, "soda_can", FIST)
    assert heading == pytest.approx(STEP, abs=1e-6)  # as fast as allowed, toward +1
    headings = [0.0]
    for _ in range(5):
        headings.append(wrist_step(headings[-1], PALM, CLOSING, pose, "soda_can", FIST))
    assert headings[-1] == pytest.approx(1.0, abs=1e-6)  # reached in 2 frames, then kept


@pytest.mark.parametrize("case", ["open", "barely", "far", "not lying"])
def test_no_turn_unless_closing_near_a_lying_cylinder(case):
    joints = {"open": np.zeros(15), "barely": np.full(15, 0.99 * CLOSING_FRACTION) * FIST}.get(case, CLOSING)
    palm = PALM + ([REACH * 1.01, 0.0, 0.0] if case == "far" else 0.0)
    name = "mug" if case == "not lying" else "paper_roll"
    assert wrist_step(0.0, palm, joints, lying_pose(1.2), name, FIST) == 0.0
    # a turned palm that stops qualifying turns back toward rest, at the rate limit
    assert wrist_step(0.8, palm, joints, lying_pose(1.2), name, FIST) == pytest.approx(0.8 - STEP, abs=1e-6)
    assert wrist_step(0.3, palm, joints, lying_pose(1.2), name, FIST) == 0.0


def test_the_target_is_the_axis_nearest_the_palm_within_a_quarter_turn():
    assert axis_target(0.0, 1.0) == pytest.approx(1.0)
    assert axis_target(0.0, 2.5) == pytest.approx(2.5 - math.pi)  # the same axis, the other way
    assert axis_target(1.4, -1.5) == pytest.approx(QUARTER_TURN)  # -1.5 + pi = 1.64, clipped
    assert axis_target(-1.4, 1.5) == pytest.approx(-QUARTER_TURN)
    assert axis_target(-0.2, -3.0) == pytest.approx(-3.0 + math.pi)


def test_random_hands_turn_within_the_rate_and_a_quarter_turn_deterministically():
    rng = np.random.default_rng(11)
    n = 400
    palm = np.column_stack([0.5 + rng.normal(0.0, 0.3, n), np.full(n, 1.0), 4.0 + rng.normal(0.0, 0.3, n)])
    joints = rng.uniform(0.0, 0.3, (n, 1)) * FIST
    poses = np.array([lying_pose(y) for y in rng.uniform(-4.0, 4.0, n)])
    for name in sorted(n for n, c in OBJECTS.items() if c.lying):
        out = wrist_headings(palm, joints, poses, name, FIST)
        assert out[0] == 0.0 and np.all(np.abs(out) <= QUARTER_TURN + 1e-6)
        assert np.abs(np.diff(out)).max() <= STEP + 1e-6
        assert np.abs(np.diff(out)).max() > 0.9 * STEP  # it did turn, at the limit somewhere
        assert np.array_equal(out, out.astype(np.float32))  # kept as recorded
        assert np.array_equal(out, wrist_headings(palm.copy(), joints.copy(), poses.copy(), name, FIST))
    assert np.all(wrist_headings(palm, joints, poses, "orange", FIST) == 0.0)
    with pytest.raises(SpecError, match="quarter turn"):
        wrist_step(2.0, PALM, CLOSING, poses[0], "soda_can", FIST)


def test_the_design_is_registered_and_turns_by_the_reflex_only():
    assert DESIGNS["opposed-wrist"] is OPPOSED_WRIST
    assert OPPOSED_WRIST.wrist_reflex and not OPPOSED_WRIST.turn_to_axis
    with pytest.raises(SpecError, match="not both"):
        dataclasses.replace(OPPOSED_WRIST, turn_to_axis=True)


@pytest.mark.parametrize("index", [0, 2, 5, 15, 18])  # paper rolls and water bottles, axes turned up to a quarter
def test_the_wrist_ground_truth_turns_by_the_reflex_and_holds(index):
    spec = spec_for("test-1k", index)
    assert OBJECTS[spec.object].lying
    hand, poses, _ = plan(spec, OPPOSED_WRIST)
    i = spec.intercept_frame
    heading = hand.palm_pose[:, 4]
    assert np.all(hand.palm_pose[: i + 1, 3:] == 0.0) and np.all(hand.palm_pose[:, [3, 5]] == 0.0)
    recorded = [np.asarray(x, np.float32).astype(np.float64) for x in (hand.palm_pose, hand.joint_angles, poses)]
    assert np.array_equal(wrist_headings(recorded[0][:, :3], recorded[1], recorded[2], spec.object, FIST), heading)
    assert heading[grasp_frame(spec)] != 0.0
    assert np.abs(np.diff(heading)).max() <= STEP + 1e-6
    out = episode_hold(spec, hand.palm_pose, hand.joint_angles, OPPOSED_WRIST)
    assert out is not None and out[0] == grasp_frame(spec) and out[1].held, (spec.object, out)


@pytest.mark.parametrize("index", [0, 15, 18])  # the palm raised for the wrist, then turned
def test_the_hand_body_with_the_reflex_reaches_the_wrist_ground_truth_exactly(index):
    """Fed the plan's 18-number actions, the body built for the design turns the palm by the
    reflex itself and reaches every recorded state (palm, joints, heading) bit for bit."""
    from generators.hand_body import HandBody

    spec = spec_for("test-1k", index)
    hand, poses, _ = plan(spec, OPPOSED_WRIST)
    action, state, joints, obj = (np.asarray(x, np.float32).astype(np.float64)
                                  for x in (hand.action, hand.palm_pose, hand.joint_angles, poses))
    body = HandBody(design=OPPOSED_WRIST)
    try:
        body.reset(spec.hand, spec.object, spec.object_size, spec.obstacles)
        for t in range(spec.observe_frames, spec.num_frames - 1):
            palm, q = body.step(action[t, :3], action[t, 3:], obj[t + 1])
            assert np.array_equal(palm, state[t + 1, :3]) and np.array_equal(q, joints[t + 1]), t
            assert body.heading == state[t + 1, 4], t
    finally:
        body.close()
    assert np.abs(state[:, 4]).max() > 0.5  # it did turn


def test_a_body_without_the_reflex_keeps_the_rest_orientation():
    from generators.hand_body import HandBody

    spec = spec_for("test-1k", 0)
    hand, poses, _ = plan(spec, OPPOSED_WRIST)
    body = HandBody(design=dataclasses.replace(OPPOSED_WRIST, name="no-reflex", wrist_reflex=False))
    try:
        body.reset(spec.hand, spec.object, spec.object_size, spec.obstacles)
        for t in range(spec.observe_frames, spec.num_frames - 1):
            body.step(hand.action[t, :3], hand.action[t, 3:], poses[t + 1])
            assert body.heading == 0.0
    finally:
        body.close()


@pytest.mark.parametrize("side", ["right", "left"])
def test_the_opposed_hands_urdf_matches_its_kinematics(tmp_path, side):
    """The body built for the design loads the opposed hand: its URDF's link frames are the
    opposed geometry's forward kinematics; it is the dataset's (5.x), the splayed hand's (4.x) differs."""
    from generators.bullet import p
    from generators.hand import DEFAULT_GEOMETRY, OPPOSED_THUMB, SPLAYED_THUMB, chain_frames
    from generators.hand_urdf import hand_urdf, joint_indices, set_hand_state, write_hand_urdf

    assert hand_urdf(side) == hand_urdf(side, DEFAULT_GEOMETRY) == hand_urdf(side, OPPOSED_THUMB) != hand_urdf(side, SPLAYED_THUMB)
    path = write_hand_urdf(side, str(tmp_path), OPPOSED_THUMB)
    assert path.endswith(f"dyana_hand_{side}.urdf")
    assert write_hand_urdf(side, str(tmp_path), SPLAYED_THUMB).endswith(f"dyana_hand_{side}_splayed-thumb.urdf")
    client = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(path, useFixedBase=True, physicsClientId=client)
        indices = joint_indices(body, client)
        palm = np.array([0.3, 1.2, 0.4, 0.0, 0.7, 0.0])
        q = np.random.default_rng(4).uniform(0.0, 1.0, 15)
        set_hand_state(body, palm, q, client, indices)
        links = np.array([p.getLinkState(body, int(j), computeForwardKinematics=True, physicsClientId=client)[4]
                          for j in indices])
    finally:
        p.disconnect(client)
    np.testing.assert_allclose(links, chain_frames(palm, q, side, OPPOSED_THUMB)[0][0, :, :3].reshape(15, 3), atol=1e-5)


def test_the_planner_lifts_the_palm_only_where_the_wrist_would_enter():
    from generators.wrist import WRIST_MARGIN, wrist_clear_heights

    pose = lying_pose(math.pi / 2, 0.0, 4.0)[None].repeat(3, axis=0)  # axis along Z, under the wrist at rest
    top = 2 * 0.33
    palm = np.array([[0.0, top + 0.13, 4.0], [0.0, top + 0.13, 4.0], [3.0, top + 0.13, 4.0]])
    heights = wrist_clear_heights(palm, np.array([0.0, math.pi / 2, 0.0]), "soda_can", OBJECTS["soda_can"].nominal_size, pose)
    assert heights[0] > top + 0.13 + 0.15  # unturned: the wrist (0.195 under the palm) over the can
    assert heights[1] == heights[2] == top + 0.13  # turned across it, or far from it: as planned
    assert heights[0] - 0.7 * 0.45 - top == pytest.approx(WRIST_MARGIN, abs=0.01)
