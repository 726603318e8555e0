"""The hand model: FK against pybullet's link states, mirror symmetry, limits, conventions."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from generators.hand import (
    JOINT_LOWER,
    JOINT_NAMES,
    JOINT_UPPER,
    KEYPOINT_NAMES,
    REST_JOINTS,
    REST_PALM,
    SIDES,
    SPLAYED_THUMB,
    chain_frames,
    euler_to_matrix,
    fingertip_positions,
    forward_kinematics,
    matrix_to_euler,
    mirror_palm_pose,
    within_limits,
)
from generators.hand_urdf import (
    hand_urdf,
    joint_indices,
    keypoint_link_indices,
    pybullet_joint_order,
    set_hand_state,
    write_hand_urdf,
)
from schemas.errors import SpecError

MIRROR = np.diag([-1.0, 1.0, 1.0])


@pytest.fixture(scope="module")
def bullet():
    client = p.connect(p.DIRECT)
    yield client
    p.disconnect(client)


def _random_states(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    palm = np.concatenate([rng.uniform(-4, 4, (n, 3)), rng.uniform(-1.45, 1.45, (n, 3))], axis=1)
    joints = rng.uniform(JOINT_LOWER, JOINT_UPPER, (n, 15))
    return palm, joints


@pytest.mark.parametrize("side", SIDES)
def test_fk_matches_pybullet_link_states(bullet, tmp_path, side):
    body = p.loadURDF(write_hand_urdf(side, str(tmp_path)), useFixedBase=True, physicsClientId=bullet)
    joints_idx = joint_indices(body, bullet)
    keypoint_idx = keypoint_link_indices(body, bullet)
    palm, joints = _random_states(np.random.default_rng(7 if side == "right" else 8), 25)
    palm[0], joints[0] = REST_PALM, REST_JOINTS
    joint_poses, keypoints = forward_kinematics(palm, joints, side)
    for k in range(len(palm)):
        set_hand_state(body, palm[k], joints[k], bullet, joints_idx)
        for index, pose in zip(
            np.concatenate([joints_idx, keypoint_idx]),
            np.concatenate([joint_poses[k].reshape(15, 6), keypoints[k].reshape(6, 6)]),
        ):
            state = p.getLinkState(body, int(index), computeForwardKinematics=True, physicsClientId=bullet)
            rot = np.array(p.getMatrixFromQuaternion(state[5])).reshape(3, 3)
            np.testing.assert_allclose(pose[:3], state[4], atol=1e-5)
            np.testing.assert_allclose(euler_to_matrix(pose[3:]), rot, atol=1e-5)
        base_pos, base_quat = p.getBasePositionAndOrientation(body, physicsClientId=bullet)
        np.testing.assert_allclose(base_pos, palm[k, :3], atol=1e-6)
    p.removeBody(body, physicsClientId=bullet)


def test_urdf_joints_and_limits_match_the_model(bullet, tmp_path):
    body = p.loadURDF(write_hand_urdf("right", str(tmp_path)), useFixedBase=True, physicsClientId=bullet)
    idx = joint_indices(body, bullet)
    assert pybullet_joint_order() == JOINT_NAMES
    for k, i in enumerate(idx):
        info = p.getJointInfo(body, int(i), physicsClientId=bullet)
        assert info[1].decode() == JOINT_NAMES[k]
        assert info[2] == p.JOINT_REVOLUTE
        assert info[8] == pytest.approx(JOINT_LOWER[k]) and info[9] == pytest.approx(JOINT_UPPER[k])
    revolute = [
        i
        for i in range(p.getNumJoints(body, physicsClientId=bullet))
        if p.getJointInfo(body, i, physicsClientId=bullet)[2] == p.JOINT_REVOLUTE
    ]
    assert len(revolute) == 15
    assert len(keypoint_link_indices(body, bullet)) == len(KEYPOINT_NAMES) == 6
    p.removeBody(body, physicsClientId=bullet)


def test_urdf_is_deterministic_and_sided(tmp_path):
    assert hand_urdf("right") == hand_urdf("right")
    assert hand_urdf("left") != hand_urdf("right")
    path = write_hand_urdf("left", str(tmp_path))
    assert open(path, encoding="utf-8").read() == hand_urdf("left")
    assert [f.name for f in tmp_path.iterdir()] == ["dyana_hand_left.urdf"]
    with pytest.raises(SpecError, match="middle"):
        hand_urdf("middle")


def test_euler_convention_matches_pybullet():
    rng = np.random.default_rng(1)
    for euler in rng.uniform(-3.1, 3.1, (20, 3)):
        rot = np.array(p.getMatrixFromQuaternion(p.getQuaternionFromEuler(euler.tolist()))).reshape(3, 3)
        np.testing.assert_allclose(euler_to_matrix(euler), rot, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-3.1, 3.1),
    st.floats(-1.5, 1.5),
    st.floats(-3.1, 3.1),
)
def test_matrix_to_euler_inverts_euler_to_matrix(roll, pitch, yaw):
    euler = np.array([roll, pitch, yaw])
    np.testing.assert_allclose(euler_to_matrix(matrix_to_euler(euler_to_matrix(euler))), euler_to_matrix(euler), atol=1e-9)
    np.testing.assert_allclose(matrix_to_euler(euler_to_matrix(euler)), euler, atol=1e-6)


def test_left_hand_is_the_mirror_of_the_right():
    palm, joints = _random_states(np.random.default_rng(3), 30)
    pos_r, rot_r = chain_frames(palm, joints, "right")
    pos_l, rot_l = chain_frames(mirror_palm_pose(palm), joints, "left")
    np.testing.assert_allclose(pos_l, pos_r @ MIRROR, atol=1e-12)
    np.testing.assert_allclose(rot_l, MIRROR @ rot_r @ MIRROR, atol=1e-12)
    _, key_r = forward_kinematics(palm, joints, "right")
    _, key_l = forward_kinematics(mirror_palm_pose(palm), joints, "left")
    np.testing.assert_allclose(key_l.reshape(-1, 6, 6)[..., 0], -key_r.reshape(-1, 6, 6)[..., 0], atol=1e-12)


def test_rest_pose_conventions():
    """Palm down, fingers forward; the splayed hand's (4.x) right thumb toward -X, left thumb
    toward +X (the opposed thumb points back: tests/generators/test_grasp_design.py)."""
    rest = REST_PALM[None]
    for side, sign in (("right", -1.0), ("left", 1.0)):
        tips = fingertip_positions(rest, REST_JOINTS[None], side, SPLAYED_THUMB)[0]
        assert sign * (tips[0, 0] - rest[0, 0]) > 0.5
        assert np.all(tips[1:, 2] > rest[0, 2] + 1.0)  # fingers point +Z
        lateral = tips[1:, 0] * -sign  # index .. little run away from the thumb side
        assert np.all(np.diff(lateral) > 0)
        curled = fingertip_positions(rest, np.tile([0.8, 0.8, 0.8], 5)[None], side, SPLAYED_THUMB)[0]
        assert np.all(curled[:, 1] < rest[0, 1] - 0.2)  # flexion curls toward the palm (-Y)
    _, key = forward_kinematics(rest, REST_JOINTS[None], "right")
    wrist = key.reshape(6, 6)[5]
    assert wrist[2] < rest[0, 2] and np.allclose(wrist[3:], 0.0)


def test_hand_size_is_human():
    pos, _ = chain_frames(REST_PALM[None], REST_JOINTS[None], "right")
    lengths = np.linalg.norm(pos[0, :, 3] - pos[0, :, 0], axis=-1)
    assert np.all((lengths[1:] > 0.6) & (lengths[1:] < 0.95))
    spread = pos[0, 1:, 0, 0].max() - pos[0, 1:, 0, 0].min()
    assert 0.5 < spread < 0.9


def test_limits():
    assert len(JOINT_NAMES) == 15 and len(set(JOINT_NAMES)) == 15
    assert np.all(JOINT_LOWER < JOINT_UPPER)
    assert within_limits(REST_JOINTS).all()
    assert not within_limits(JOINT_UPPER + 0.01).any()
    assert not within_limits(JOINT_LOWER - 0.01).any()


def test_bad_inputs_are_rejected():
    with pytest.raises(SpecError, match="side"):
        forward_kinematics(REST_PALM[None], REST_JOINTS[None], "both")
    with pytest.raises(SpecError, match="joint_angles"):
        forward_kinematics(REST_PALM[None], np.zeros((1, 14)), "right")
