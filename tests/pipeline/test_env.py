"""The closed-loop environment: the contract checker, ground-truth reproduction,
determinism, invalid actions, the observe window, the horizon and termination."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from catalog.tables.shard import rollout_frame_limit
from generators.encode import JPEG_QUALITY, decode_jpeg
from generators.grasp import grasp_angles
from generators.hand import JOINT_LOWER, JOINT_UPPER, REST_JOINTS, REST_PALM
from generators.hand_body import JOINT_MAX_SPEED, PALM_MAX_ACCELERATION, limit_palm
from generators.recipe import spec_for
from pipeline.loop.actions import as_chunk, run_chunk
from pipeline.loop.env import ENV_ID, FULL_ENV_ID, DyanaEnv, SliceEpisodes, horizon
from pipeline.loop.env_checker import check_env
from pipeline.loop.spaces import PALM_BOX
from pipeline.loop.wrappers import RecordEpisode, loop_env
from pipeline.stages.episode import episode
from pipeline.stages.record import encoded_frames
from schemas.errors import DyanaError, PolicyError, SpecError
from schemas.scene import GRASP_RATIO, PHASES

RES = 64
OBSERVE, APPROACH, GRASP, HOLD = (PHASES.index(p) for p in ("observe", "approach", "grasp", "hold"))
#: test-1k episodes: 0 linear direct-act, 2 linear with a window, 4 circular, 7 harmonic.
EPISODES = (0, 2, 4, 7)


@pytest.fixture(scope="module")
def env() -> RecordEpisode:
    return loop_env(RES, episodes=SliceEpisodes("test-1k"))


def hold(obs: dict) -> np.ndarray:
    return np.concatenate([obs["palm_pose"][:3], obs["joint_angles"]]).astype(np.float32)


def run(env: RecordEpisode, spec, actions) -> tuple:
    obs, info = env.reset(options={"spec": spec})
    out = (obs, 0.0, False, False, info)
    for action in actions:
        out = env.step(action)
        if out[2] or out[3]:
            break
    return out, env.recording()


def test_check_env_passes(env):
    check_env(env, spec_for("test-1k", 7))


def test_check_env_passes_direct_act(env):
    spec = spec_for("test-1k", 0)
    assert spec.observe_frames == 0
    check_env(env, spec)


def test_check_env_catches_a_broken_environment(env):
    class Leaky(RecordEpisode):
        def step(self, action):  # repairs NaN/inf instead of refusing them
            if isinstance(action, np.ndarray) and action.shape == (18,):
                action = np.nan_to_num(action, posinf=0.0, neginf=0.0)
            return super().step(action)

    with pytest.raises(AssertionError, match="accepted"):
        check_env(Leaky(DyanaEnv(RES)), spec_for("test-1k", 2), steps=2)


@pytest.mark.parametrize("index", EPISODES)
def test_ground_truth_actions_reproduce_the_ground_truth(env, index):
    spec = spec_for("test-1k", index)
    gt = episode(spec)
    a = spec.observe_frames
    (_, reward, terminated, truncated, info), (frames, images) = run(env, spec, gt.action[a:])
    n = frames.num_frames
    # the episode ends at grasp completion, the first frame with every joint >= 80% of the grasp
    closed = np.all(gt.joint_angles.astype(np.float64) >= GRASP_RATIO * gt.grasp_angles.astype(np.float64), axis=1)
    completion = int(np.flatnonzero(closed & (np.arange(spec.num_frames) >= a))[0])
    assert terminated and not truncated and reward == 1.0
    assert n == completion + 1 and info["t_gra"] == completion - a and info["localized"]
    for name in ("object_pose", "object_velocity", "palm_pose", "joint_angles", "grasp_angles"):
        expected = getattr(gt, name) if name == "grasp_angles" else getattr(gt, name)[:n]
        np.testing.assert_array_equal(getattr(frames, name), expected, err_msg=name)
    # forward kinematics runs on the float32 states the recording keeps, the ground
    # truth on its float64 plan: at most a float32 rounding step apart
    for name in ("joint_poses", "keypoints", "fingertip_distance", "palm_distance"):
        np.testing.assert_allclose(getattr(frames, name), getattr(gt, name)[:n], rtol=0, atol=2e-6, err_msg=name)
    np.testing.assert_array_equal(frames.action[:-1], gt.action[: n - 1])
    state = np.concatenate([frames.palm_pose[-1, :3], frames.joint_angles[-1]])
    np.testing.assert_array_equal(frames.action[-1], state)
    assert images == encoded_frames(spec, gt, RES, JPEG_QUALITY)[:n]
    # intended difference: phases follow the events, not the plan
    np.testing.assert_array_equal(frames.phase[:a], gt.phase[:a])
    t_loc = a + info["t_loc"]
    assert np.all(frames.phase[a:t_loc] == APPROACH) and np.all(frames.phase[t_loc:] == GRASP)
    assert t_loc <= spec.intercept_frame and gt.phase[spec.intercept_frame] == GRASP


def test_same_actions_give_identical_recordings(env):
    spec = spec_for("test-1k", 4)
    rng = np.random.default_rng(7)
    low = np.concatenate([[-3.0, 0.5, 1.0], JOINT_LOWER])
    high = np.concatenate([[3.0, 4.0, 8.0], JOINT_UPPER * 0.5])
    actions = rng.uniform(low, high, size=(12, 18))
    _, (f1, i1) = run(env, spec, actions)
    _, (f2, i2) = run(loop_env(RES), spec, actions)
    for name in ("phase", "object_pose", "palm_pose", "joint_angles", "joint_poses", "keypoints", "action",
                 "fingertip_distance", "palm_distance"):
        assert getattr(f1, name).tobytes() == getattr(f2, name).tobytes(), name
    assert i1 == i2
    # float64 actions are recorded, and executed, as float32
    np.testing.assert_array_equal(f1.action[spec.observe_frames : spec.observe_frames + 12], actions.astype(np.float32))


@pytest.mark.parametrize(
    "bad, message",
    [
        (lambda a: np.where(np.arange(18) == 3, np.nan, a), "NaN/inf at index 3"),
        (lambda a: np.where(np.arange(18) == 17, -np.inf, a), "NaN/inf at index 17"),
        (lambda a: a[:17], r"shape \(18,\), got \(17,\)"),
        (lambda a: np.stack([a, a]), r"got \(2, 18\)"),
        (lambda a: "grasp", "not a numeric array"),
        (lambda a: None, "shape"),
    ],
)
def test_invalid_actions_raise_and_change_nothing(env, bad, message):
    spec = spec_for("test-1k", 2)
    obs, _ = env.reset(options={"spec": spec})
    with pytest.raises(PolicyError, match=message):
        env.step(bad(hold(obs)))
    assert env.recording()[0].num_frames == spec.observe_frames + 1
    obs, *_ = env.step(hold(obs))
    assert obs["frame_index"] == spec.observe_frames + 1


def test_observe_window_holds_the_hand_still(env):
    spec = spec_for("test-1k", 4)
    a = spec.observe_frames
    obs, info = env.reset(options={"spec": spec})
    assert obs["observe_images"].shape == (a, RES, RES, 3) and obs["frame_index"] == a
    assert obs["timestamp"] == a / 20 and obs["text"] == spec.text
    assert obs["timestamp"].dtype == np.float64 and obs["timestamp"].shape == () and float(obs["timestamp"]) == a / 20
    assert not info["localized"] and info["t_loc"] == -1
    frames, images = env.recording()
    assert np.all(frames.phase[:a] == OBSERVE) and frames.phase[a] == APPROACH
    np.testing.assert_array_equal(frames.palm_pose, np.broadcast_to(REST_PALM.astype(np.float32), (a + 1, 6)))
    np.testing.assert_array_equal(frames.joint_angles, np.zeros((a + 1, 15), dtype=np.float32))
    rest_action = np.concatenate([REST_PALM[:3], REST_JOINTS]).astype(np.float32)
    np.testing.assert_array_equal(frames.action[:a], np.broadcast_to(rest_action, (a, 18)))
    for k in (0, a // 2, a - 1):
        np.testing.assert_array_equal(obs["observe_images"][k], decode_jpeg(images[k]))
    np.testing.assert_array_equal(obs["image"], decode_jpeg(images[a]))
    assert len({images[k] for k in range(a)}) > a // 2  # the object moves while the hand waits
    obs, *_ = env.step(hold(obs))
    assert obs["observe_images"].shape == (0, RES, RES, 3)


def test_horizon_truncates_a_still_hand(env):
    spec = spec_for("test-1k", 6)
    a, h = spec.observe_frames, horizon(spec)
    assert h == -(-6 * (spec.num_frames - a) // 5) == rollout_frame_limit(spec) - a
    obs, _ = env.reset(options={"spec": spec})
    steps = 0
    while True:
        obs, reward, terminated, truncated, info = env.step(hold(obs))
        steps += 1
        if terminated or truncated:
            break
    assert truncated and not terminated and reward == 0.0 and steps == h - 1
    assert env.recording()[0].num_frames == a + h
    assert not info["localized"] and not info["grasped"]
    with pytest.raises(DyanaError, match="ended"):
        env.step(hold(obs))


def test_terminates_when_the_grasp_completes(env):
    spec = spec_for("test-1k", 2)
    grasp = grasp_angles(spec.object, spec.object_size, spec.hand)
    obs, _ = env.reset(options={"spec": spec})
    ramp = [0.3, 0.6, 0.79, 0.81, 1.0]  # fractions of the grasp; complete at 0.8
    for j, fraction in enumerate(ramp):  # noqa: B007  (j is read after the loop)
        action = np.concatenate([obs["palm_pose"][:3], fraction * grasp])
        obs, reward, terminated, truncated, info = env.step(action)
        if terminated:
            break
    assert terminated and j == 3 and reward == 1.0 and info["grasped"] and info["t_gra"] == 4
    assert not info["localized"]  # grasp is judged on the fingers alone
    frames, _ = env.recording()
    assert frames.num_frames == spec.observe_frames + 5
    assert np.all(frames.phase[spec.observe_frames :] == APPROACH)


def test_actions_are_clipped_to_the_palm_box_and_joint_limits_then_followed_within_the_body_limits(env):
    spec = spec_for("test-1k", 2)
    obs, _ = env.reset(options={"spec": spec})
    action = np.concatenate([[100.0, -5.0, -100.0], JOINT_UPPER + 1.0])
    obs, *_ = env.step(action)
    corner = np.array([PALM_BOX[0][1], PALM_BOX[1][0], PALM_BOX[2][0]])
    reached = limit_palm(REST_PALM[:3], np.zeros(3), corner)  # from rest, toward the clipped target
    assert 0.0 < np.linalg.norm(reached - REST_PALM[:3]) <= PALM_MAX_ACCELERATION / 20**2 + 1e-12
    np.testing.assert_array_equal(obs["palm_pose"][:3], reached.astype(np.float32))
    np.testing.assert_array_equal(obs["joint_angles"], np.minimum(JOINT_UPPER, JOINT_MAX_SPEED / 20).astype(np.float32))
    np.testing.assert_array_equal(obs["palm_pose"][3:], REST_PALM[3:].astype(np.float32))
    frames, _ = env.recording()
    np.testing.assert_array_equal(frames.action[spec.observe_frames], action.astype(np.float32))  # as issued


def test_run_chunk_executes_rows_and_checks_the_whole_chunk_first(env):
    spec = spec_for("test-1k", 2)
    obs, _ = env.reset(options={"spec": spec})
    chunk = np.repeat(hold(obs)[None], 3, axis=0)
    result = run_chunk(env, chunk)
    assert result.steps == 3 and result.observation["frame_index"] == spec.observe_frames + 3
    bad = chunk.copy()
    bad[2, 5] = np.nan
    with pytest.raises(PolicyError, match="row 2, column 5"):
        run_chunk(env, bad)
    assert env.recording()[0].num_frames == spec.observe_frames + 4
    assert as_chunk(hold(obs)).shape == (1, 18)
    with pytest.raises(PolicyError):
        as_chunk(np.zeros((0, 18)))


def test_reset_accepts_specs_dicts_json_and_seeds(env):
    spec = spec_for("test-1k", 3)
    for given in (spec, spec.to_dict(), spec.to_json()):
        obs, _ = env.reset(options={"spec": given})
        assert env.episode_spec == spec and obs["frame_index"] == spec.observe_frames
    env.reset(seed=1003)
    assert env.episode_spec == spec
    with pytest.raises(SpecError, match="must be an EpisodeSpec"):
        env.reset(options={"spec": 42})
    with pytest.raises(SpecError):
        env.reset(options={"spec": "{not json"})
    with pytest.raises(DyanaError, match="before reset"):
        DyanaEnv(RES).step(np.zeros(18))
    # where a spec-less reset takes its episode is the env's argument, never a hidden default
    with pytest.raises(SpecError, match="episodes source"):
        DyanaEnv(RES).reset(seed=3)
    custom = DyanaEnv(RES, episodes=[spec_for("test-1k", 9), spec])
    custom.reset(seed=3)
    assert custom.episode_spec == spec
    custom.reset()
    assert custom.episode_spec == spec_for("test-1k", 9)  # the one after the last picked, wrapping
    custom.close()


def test_bad_constructor_arguments():
    for kwargs in ({"resolution": 4}, {"resolution": True}, {"jpeg_quality": 0}, {"render_mode": "human"},
                   {"renderer": "tiny"}):
        with pytest.raises(SpecError):
            DyanaEnv(**kwargs)


@pytest.mark.parametrize("episodes", [1.5, [], {}, b"x", object()])
def test_an_episodes_source_that_is_not_one_is_refused_when_made(episodes):
    """Before: accepted, then reset() failed with ZeroDivisionError or TypeError from '%'."""
    with pytest.raises(SpecError, match="episodes must be a slice name, a non-empty sequence"):
        DyanaEnv(resolution=16, episodes=episodes)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"seed": "3"}, "seed must be None or an integer >= 0, got '3'"),
    ({"seed": 1.5}, "seed must be None or an integer >= 0"),
    ({"seed": -1}, "seed must be None or an integer >= 0"),
    ({"options": "spec"}, "options must be None or a dict"),
    ({"options": 3}, "options must be None or a dict"),
])
def test_reset_names_a_bad_seed_or_options(kwargs, message):
    """Before: gymnasium.error.Error ('Seed must be a python integer') or AttributeError
    ('str' object has no attribute 'get')."""
    env = DyanaEnv(resolution=16, episodes="linear-fast")
    with pytest.raises(SpecError, match=message):
        env.reset(**kwargs)
    env.close()


#: Run in a fresh interpreter that imports only gymnasium (not Dyana): make, reset and step
#: through the passive checker, FlattenObservation, then Gymnasium's check_env (render
#: check included) on the unwrapped and the wrapped environment, recording its warnings.
FRESH_GYMNASIUM = """
import json, sys, warnings
import gymnasium
from gymnasium.utils.env_checker import check_env
from gymnasium.wrappers import FlattenObservation

assert not any(name.split(".")[0] in ("pipeline", "generators", "schemas") for name in sys.modules)
out = {}
with warnings.catch_warnings():
    warnings.simplefilter("error")  # any warning from make/reset/step/flatten fails
    env = gymnasium.make("pipeline.loop.env:Dyana/GraspFull-v0", resolution=64)
    out["wrappers"] = str(env)
    obs, info = env.reset(seed=2)
    out["reset"] = [obs["frame_index"], len(obs["observe_images"]), float(obs["timestamp"])]
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    out["step"] = [obs["frame_index"], len(obs["observe_images"]), float(obs["timestamp"])]
    flat = FlattenObservation(gymnasium.make("Dyana/GraspFull-v0", resolution=64))
    first, _ = flat.reset(seed=2)
    then = flat.step(flat.action_space.sample())[0]
    out["flat"] = [flat.observation_space.shape, first.shape, then.shape, first in flat.observation_space,
                   then in flat.observation_space, float(first[-1]), float(then[-1])]
for name, target in (("unwrapped", env.unwrapped), ("wrapped", env)):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(target)
    out[name] = sorted({str(w.message) for w in caught})
print(json.dumps(out))
"""
#: The one warning Gymnasium's check_env gives that Dyana keeps by design (module
#: docstring: the action is the dataset's, in scene units and radians).
NORMALIZED_ACTIONS = "For Box action spaces, we recommend using a symmetric and normalized space"


def fresh(script: str) -> dict:
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(script)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_gymnasium_make_check_env_and_flatten_in_a_fresh_interpreter():
    pytest.importorskip("gymnasium")
    out = fresh(FRESH_GYMNASIUM)
    a = spec_for("test-1k", 2).observe_frames
    assert "PassiveEnvChecker" in out["wrappers"]  # the passive checker runs (and said nothing)
    assert out["reset"] == [a, a, a / 20] and out["step"] == [a + 1, 0, (a + 1) / 20]
    (size,), first, then, first_in, then_in, first_stamp, then_stamp = out["flat"]
    assert first == then == [size] and first_in and then_in
    assert (first_stamp, then_stamp) == (a / 20, (a + 1) / 20)  # the last entry: the timestamp, sorted last
    # the only warning left is the normalised-action advice; on the wrapped env Gymnasium
    # also says it is not the raw one (it always does)
    assert len(out["unwrapped"]) == 1 and NORMALIZED_ACTIONS in out["unwrapped"][0], out["unwrapped"]
    wrapped = [w for w in out["wrapped"] if "is different from the unwrapped version" not in w]
    assert len(out["wrapped"]) == 2 and wrapped == out["unwrapped"], out["wrapped"]


def test_the_gymnasium_entry_point_registers_the_environment():
    """pyproject's ``gymnasium.envs`` entry point, called the way Gymnasium 0.26-0.29 call
    plugins on ``import gymnasium`` (inside the entry point's namespace); Gymnasium 1.x no
    longer loads plugins, hence the explicit call here."""
    pytest.importorskip("gymnasium")
    out = fresh("""
    import json, sys, warnings
    from importlib.metadata import entry_points
    import gymnasium
    from gymnasium.envs.registration import namespace

    warnings.simplefilter("error")
    assert "Dyana/Grasp-v0" not in gymnasium.registry and "pipeline.loop.env" not in sys.modules
    plugins = [[e.name, e.value] for e in entry_points(group="gymnasium.envs") if e.value.startswith("pipeline.")]
    (plugin,) = [e for e in entry_points(group="gymnasium.envs") if e.value.startswith("pipeline.")]
    with namespace(plugin.name):
        registered = plugin.load()()
    again = plugin.load()()  # idempotent
    env = gymnasium.make("Dyana/GraspFull-v0", resolution=64)
    obs, _ = env.reset(seed=0)
    print(json.dumps({"plugins": plugins, "ids": [k for k in gymnasium.registry if k.startswith("Dyana")],
                      "registered": [registered, again], "frame": obs["frame_index"]}))
    """)
    assert out["plugins"] == [["Dyana", "pipeline.loop.registration:register"]]
    assert out["ids"] == [ENV_ID, FULL_ENV_ID] and out["registered"] == [True, True] and out["frame"] == 0


def test_every_observation_lies_in_its_space_even_at_the_limits(env):
    """The bounds are what the environment enforces: actions pinned at the palm box's
    corners and the joint limits, and beyond them, give observations inside the space."""
    gymnasium = pytest.importorskip("gymnasium")
    spec = spec_for("test-1k", 4)
    obs, _ = env.reset(options={"spec": spec})
    assert obs in env.observation_space
    low, high = env.action_space.low, env.action_space.high
    corners = [np.where(np.arange(18) % 2 == j, low, high) for j in (0, 1)] + [low - 5.0, high + 5.0, low, high]
    for action in corners:
        obs, _, terminated, truncated, _ = env.step(action)
        for key, space in env.observation_space.spaces.items():
            assert space.contains(obs[key]), key
        if terminated or truncated:  # the joints at their upper limits complete the grasp
            env.reset(options={"spec": spec})
    for key in ("palm_pose", "joint_angles", "joint_poses", "keypoints"):
        space = env.observation_space[key]
        assert np.isfinite(space.low).all() and np.isfinite(space.high).all(), key
    assert np.isfinite(env.observation_space["timestamp"].high)
    # a learner that wants [-1, 1] actions rescales the finite Box
    rescaled = gymnasium.wrappers.RescaleAction(DyanaEnv(RES), np.float32(-1), np.float32(1))
    rescaled.reset(options={"spec": spec})
    np.testing.assert_allclose(rescaled.action(np.ones(18, dtype=np.float32)), high, rtol=1e-6)
    obs, *_ = rescaled.step(np.ones(18, dtype=np.float32))  # the hand heads there, within the body's limits
    assert np.all(obs["palm_pose"][:3] > REST_PALM[:3]) and np.all(obs["joint_angles"] > 0)


def test_flattened_observations_are_the_current_frame(env):
    """FlattenObservation keeps every key but the observe window, which flattens to
    nothing (it is only in the first observation, and a fixed shape would pad every step)."""
    gymnasium = pytest.importorskip("gymnasium")
    from gymnasium.spaces.utils import flatdim, flatten, unflatten

    spec = spec_for("test-1k", 4)
    flat = gymnasium.wrappers.FlattenObservation(DyanaEnv(RES))
    space = flat.unwrapped.observation_space
    window = space["observe_images"]
    assert window.is_np_flattenable and flatdim(window) == 0
    assert unflatten(window, flatten(window, np.zeros((3, RES, RES, 3), np.uint8))).shape == (0, RES, RES, 3)
    first, _ = flat.reset(options={"spec": spec})
    then = flat.step(np.zeros(18))[0]
    obs, _ = env.reset(options={"spec": spec})  # the same episode, unflattened
    assert obs["observe_images"].shape[0] == spec.observe_frames > 0
    assert first.shape == then.shape == flat.observation_space.shape == (flatdim(space),)
    # compact: the image, the hand's 147 numbers, the frame index and the timestamp (no
    # one-hot frame index, no text)
    assert flatdim(space) == RES * RES * 3 + 6 + 15 + 90 + 36 + 1 + 1
    assert first[0] == spec.observe_frames  # the frame index, the first key in sorted order
    assert unflatten(space["frame_index"], flatten(space["frame_index"], 7)) == 7
    assert first in flat.observation_space and then in flat.observation_space
    assert np.array_equal(first, flatten(space, obs))
    no_window = dict(obs, observe_images=np.zeros((0, RES, RES, 3), np.uint8))
    assert np.array_equal(first, flatten(space, no_window))  # the window leaves no trace
    obs = env.step(np.zeros(18))[0]
    assert np.array_equal(then, flatten(space, obs))
    assert then[-1] == (spec.observe_frames + 1) / 20  # the timestamp, the last key in sorted order
    # the space is still a Sequence for the rest: contains, sample
    assert window.contains(np.zeros((3, RES, RES, 3), np.uint8)) and not window.contains(np.zeros((3, RES, RES), np.uint8))
    assert window.sample().shape[1:] == (RES, RES, 3)


def test_the_recording_keeps_actions_a_policy_later_reuses(env):
    """A policy may return the same buffer every call and refill it: the recording must
    hold each action as issued, not the buffer's last contents."""
    from pipeline.loop.rollout import run_episode
    from pipeline.policies.base import state_action

    class Reusing:
        name, action_horizon, privileged = "reusing", 1, False

        def reset(self, task):
            self.buffer, self.issued = None, []

        def act(self, obs):
            if self.buffer is None:
                self.buffer = state_action(obs)
            self.buffer[0] += np.float32(0.01)
            self.issued.append(self.buffer.copy())
            return self.buffer

    spec = spec_for("test-1k", 2)
    policy = Reusing()
    result = run_episode(env, policy, spec, 5.0)
    recorded = result.frames.action[spec.observe_frames : spec.observe_frames + len(policy.issued)]
    assert result.status == "ok" and len(policy.issued) > 2
    np.testing.assert_array_equal(recorded, np.stack(policy.issued))


@pytest.mark.parametrize("resolution", [10**6, 1025, 7, 2**70])
def test_an_unrenderable_resolution_is_refused_before_allocating(resolution):
    from schemas.errors import SpecError

    with pytest.raises(SpecError, match=r"resolution must be an integer in \[8, 1024\]"):
        DyanaEnv(resolution=resolution)


@pytest.mark.parametrize("spec", [None, "test-1k", {"episode_index": 0}])
def test_the_api_episode_names_a_spec_that_is_not_one(spec):
    import pipeline
    from schemas.errors import SpecError

    with pytest.raises(SpecError, match="spec must be a schemas.spec.EpisodeSpec"):
        pipeline.episode(spec)


def test_kinematics_kept_while_the_hand_holds_are_the_hand_state_s_own(env):
    """The env keeps the last hand state's forward kinematics while the state repeats: every
    observation's joint poses and keypoints still equal measure_hand of its own state,
    through holds, moves, a return to an earlier state and a new episode with the other hand."""
    from pipeline.stages.episode import measure_hand

    assert spec_for("test-1k", 0).hand != spec_for("test-1k", 4).hand
    for index in (0, 4):
        spec = spec_for("test-1k", index)
        obs, _ = env.reset(options={"spec": spec})
        still = hold(obs)
        moved = still.copy()
        moved[0] += 0.05
        moved[5] += 0.3
        for action in (still, still, moved, moved, still, moved):
            obs, _, terminated, truncated, _ = env.step(action)
            fresh = measure_hand(spec, obs["palm_pose"][None], obs["joint_angles"][None],
                                 env.unwrapped.object_pose[obs["frame_index"]][None])
            np.testing.assert_array_equal(obs["joint_poses"], fresh.joint_poses[0])
            np.testing.assert_array_equal(obs["keypoints"], fresh.keypoints[0])
            assert not (terminated or truncated)
