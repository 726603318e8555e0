"""The hand as a body (issue 38): a teleporting, table-diving, obstacle-ramming policy's
recorded palm obeys the speed and acceleration limits and enters nothing; the ground
truth passes through the body unchanged; the same actions give the same bytes."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from generators.clearance import box_signed_distance
from generators.hand import JOINT_LOWER, JOINT_UPPER, chain_frames
from generators.hand_body import (
    JOINT_MAX_SPEED,
    PALM_MAX_ACCELERATION,
    PALM_MAX_SPEED,
    TOUCH,
    HandBody,
    limit_joints,
    limit_palm,
)
from generators.recipe import spec_for
from pipeline.loop.env import SliceEpisodes
from pipeline.loop.spaces import PALM_HIGH, PALM_LOW
from pipeline.loop.wrappers import loop_env
from pipeline.stages.episode import episode
from schemas.versions import FPS
from tests.pipeline.in_thread import fresh_json

RES = 32
#: Episodes the adversary plays: one with obstacles, a linear one, an irregular object.
ADVERSARY = (("obstacle-medium", 1), ("test-1k", 2), ("test-irregular", 3))


def adversary_actions(env, spec, seed: int) -> list[np.ndarray]:
    """Plays ``spec`` with a seeded adversary: every frame a jump to a new target, at
    table height, into an obstacle, onto the object, or anywhere in the palm box."""
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(options={"spec": spec})
    sim = env.unwrapped
    actions: list[np.ndarray] = []
    while not sim.done:
        choice = int(rng.integers(4))
        if choice == 0:
            palm = rng.uniform(PALM_LOW, PALM_HIGH) * (1.0, 0.0, 1.0)  # at table height
        elif choice == 1 and spec.obstacles:
            palm = np.asarray(spec.obstacles[int(rng.integers(len(spec.obstacles)))].position)
        elif choice == 2:
            palm = sim.object_pose[min(sim.current_frame + 1, len(sim.object_pose) - 1), :3].astype(np.float64)
        else:
            palm = rng.uniform(PALM_LOW, PALM_HIGH)
        action = np.concatenate([palm, rng.uniform(JOINT_LOWER, JOINT_UPPER)]).astype(np.float32)
        actions.append(action)
        env.step(action)
    return actions


@pytest.fixture(scope="module")
def played():
    env = loop_env(RES, episodes=SliceEpisodes("test-1k"))
    out = []
    for k, (name, index) in enumerate(ADVERSARY):
        spec = spec_for(name, index)
        actions = adversary_actions(env, spec, seed=k)
        frames, jpegs = env.recording()
        out.append((spec, actions, frames, jpegs))
    env.close()
    return out


def test_limit_palm_reaches_a_target_within_the_limits_exactly_and_clamps_beyond():
    palm, velocity = np.array([0.1, 1.0, 2.0]), np.array([0.3, 0.0, -0.2])
    target = palm + velocity + np.array([0.5, -0.3, 0.1])
    assert limit_palm(palm, velocity, target) is not target
    np.testing.assert_array_equal(limit_palm(palm, velocity, target), target)
    far = limit_palm(palm, -velocity, palm + np.array([40.0, 0.0, 0.0]))  # turning: the acceleration binds
    assert np.linalg.norm(far - palm + velocity) == pytest.approx(PALM_MAX_ACCELERATION / FPS**2)
    assert np.linalg.norm(far - palm) < PALM_MAX_SPEED / FPS
    fast = limit_palm(palm, np.array([PALM_MAX_SPEED / FPS, 0.0, 0.0]), palm + np.array([0.0, 0.0, 40.0]))
    assert np.linalg.norm(fast - palm) == pytest.approx(PALM_MAX_SPEED / FPS)
    joints = np.zeros(15)
    np.testing.assert_array_equal(limit_joints(joints, np.full(15, 0.5)), np.full(15, 0.5))
    np.testing.assert_allclose(limit_joints(joints, np.full(15, -3.0)), np.full(15, -JOINT_MAX_SPEED / FPS))


def test_an_adversary_s_palm_obeys_the_limits_and_enters_nothing(played):
    checker = HandBody()
    blocked = 0
    for spec, actions, frames, _ in played:
        palm = frames.palm_pose[:, :3].astype(np.float64)
        joints = frames.joint_angles.astype(np.float64)
        speed = np.linalg.norm(np.diff(palm, axis=0), axis=1) * FPS
        acceleration = np.linalg.norm(np.diff(palm, 2, axis=0), axis=1) * FPS**2
        assert speed.max() <= PALM_MAX_SPEED * (1 + 1e-6)
        assert acceleration.max() <= PALM_MAX_ACCELERATION * (1 + 1e-5)
        assert np.abs(np.diff(joints, axis=0)).max() * FPS <= JOINT_MAX_SPEED * (1 + 1e-6)
        assert np.all(palm >= PALM_LOW.astype(np.float32)) and np.all(palm <= PALM_HIGH.astype(np.float32))
        # independent of pybullet: the palm, every joint and fingertip stay out of the
        # table and the obstacles (the finger cylinders' axes lie a radius > TOUCH inside them)
        points = chain_frames(frames.palm_pose, joints, spec.hand)[0].reshape(len(palm), -1, 3)
        points = np.concatenate([palm[:, None], points], axis=1)
        assert points[..., 1].min() >= -TOUCH
        for obstacle in spec.obstacles:
            assert box_signed_distance(points, obstacle).min() >= -TOUCH
        # the body's own measure, from a fresh body: the table and obstacles within TOUCH,
        # and the palm never pushed deeper into the object than it was
        checker.reset(spec.hand, spec.object, spec.object_size, spec.obstacles)
        for k in range(1, len(palm)):
            fixed, inside = checker.depths(palm[k], joints[k], frames.object_pose[k])
            assert fixed <= TOUCH + 1e-6, (spec.object, k, fixed)
            before = checker.depths(palm[k - 1], joints[k - 1], frames.object_pose[k])[1]
            assert inside <= max(TOUCH, before) + 1e-6, (spec.object, k, inside, before)
        issued = np.stack(actions)[:, :3]
        blocked += int(np.sum(np.linalg.norm(issued - palm[spec.observe_frames + 1 :], axis=1) > 0.5))
    checker.close()
    assert blocked > 10  # the adversary did try: its targets were mostly not reached


def fingerprint(played) -> str:
    digest = hashlib.sha256()
    for _, actions, frames, jpegs in played:
        digest.update(np.stack(actions).tobytes())
        for name in ("palm_pose", "joint_angles", "keypoints", "phase"):
            digest.update(np.ascontiguousarray(getattr(frames, name)).tobytes())
        for data in jpegs:
            digest.update(data)
    return digest.hexdigest()


def states_digest(played) -> str:
    """sha256 of the adversary's recorded palm and joint states alone (no image bytes)."""
    digest = hashlib.sha256()
    for _, _, frames, _ in played:
        digest.update(frames.palm_pose.tobytes())
        digest.update(frames.joint_angles.tobytes())
    return digest.hexdigest()


#: The adversary's recorded states on the host that wrote this test: another host, worker
#: count or load must give these bytes (the body is single-threaded and steps no time).
ADVERSARY_STATES = "496ac3360394286f341b5c8f897949f9b694535bae7016041dd508e9ebc07c25"


def test_the_same_actions_give_the_same_bytes_twice_after_other_episodes_and_in_a_fresh_interpreter(played):
    env = loop_env(RES, episodes=SliceEpisodes("test-1k"))
    again = []
    for spec, actions, _, _ in reversed(played):  # another order: a body reused across scenes
        env.reset(options={"spec": spec})
        for action in actions:
            env.step(action)
        again.append((spec, actions, *env.recording()))
    env.close()
    assert fingerprint(reversed(again)) == fingerprint(played)
    assert fresh_json("tests.pipeline.test_hand_body", "replay", "7") == [fingerprint(played), states_digest(played)]
    assert states_digest(played) == ADVERSARY_STATES


def replay() -> list[str]:
    """The adversary's fingerprint and state digest, computed afresh (a subprocess calls this)."""
    env = loop_env(RES, episodes=SliceEpisodes("test-1k"))
    out = []
    for k, (name, index) in enumerate(ADVERSARY):
        spec = spec_for(name, index)
        actions = adversary_actions(env, spec, seed=k)
        out.append((spec, actions, *env.recording()))
    env.close()
    return [fingerprint(out), states_digest(out)]


@pytest.mark.parametrize("slice_name, indices", [
    ("test-1k", range(0, 1000, 25)), ("obstacle-medium", range(0, 600, 60)), ("test-irregular", range(0, 99, 10)),
])
def test_the_ground_truth_passes_through_the_body_unchanged(slice_name, indices):
    body = HandBody((PALM_LOW, PALM_HIGH))
    for index in indices:
        spec = spec_for(slice_name, index)
        gt = episode(spec)
        body.reset(spec.hand, spec.object, spec.object_size, spec.obstacles)
        for k in range(spec.observe_frames, spec.num_frames - 1):
            palm, joints = body.step(gt.action[k, :3], gt.action[k, 3:], gt.object_pose[k + 1])
            np.testing.assert_array_equal(palm.astype(np.float32), gt.palm_pose[k + 1, :3], err_msg=f"{index} {k}")
            np.testing.assert_array_equal(joints.astype(np.float32), gt.joint_angles[k + 1], err_msg=f"{index} {k}")
            # the wrist reflex's heading, as the ground truth records it
            assert np.float32(body.heading) == gt.palm_pose[k + 1, 4], f"{index} {k}"
    body.close()
