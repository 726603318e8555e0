"""The environment in the Gymnasium ecosystem: its options (observation views, normalised
actions), the registered ids' defaults, Stable-Baselines3 and vector environments taking
``gymnasium.make("Dyana/Grasp-v0")`` with no options, and Gymnasium 0.29 (which loads
plugins on import) with Dyana imported first."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest

from generators.hand import JOINT_LOWER, JOINT_UPPER
from pipeline.loop.env import ENV_ID, FULL_ENV_ID, DyanaEnv
from pipeline.loop.spaces import PALM_HIGH, PALM_LOW
from pipeline.loop.views import STATE_WIDTH, VIEWS, absolute_action, state_vector
from pipeline.loop.wrappers import RecordEpisode
from schemas.errors import DyanaError, PolicyError

#: Stable-Baselines3's NatureCNN needs images of at least 36 px.
RES = 40
SEED = 4  # test-1k episode 4: an observe window of 25 frames


def learner_env(**options) -> gymnasium.Env:
    return gymnasium.make(ENV_ID, resolution=RES, **options)


def plain_env() -> gymnasium.Env:
    return gymnasium.make(ENV_ID)


def test_the_registered_ids_defaults():
    """``Dyana/Grasp-v0``: the image and state view, actions in [-1, 1] (what learners take);
    ``Dyana/GraspFull-v0``: the full dict and real actions, as ``DyanaEnv()``'s own defaults."""
    plain, full = gymnasium.make(ENV_ID), gymnasium.make(FULL_ENV_ID, resolution=RES)
    assert (plain.unwrapped.obs, plain.unwrapped.normalize_actions, plain.unwrapped.resolution) == ("both", True, 224)
    assert plain.observation_space == VIEWS["both"].space(224)
    assert plain.action_space == gymnasium.spaces.Box(-1.0, 1.0, (18,), np.float32)
    direct = DyanaEnv(RES)
    assert (full.unwrapped.obs, full.unwrapped.normalize_actions) == (direct.obs, direct.normalize_actions) == ("full", False)
    assert full.observation_space == direct.observation_space and full.action_space == direct.action_space
    overridden = gymnasium.make(ENV_ID, resolution=RES, obs="full", normalize_actions=False)
    assert overridden.observation_space == direct.observation_space


def test_each_view_shows_the_full_observation_in_its_own_space():
    full = DyanaEnv(RES, episodes="test-1k")
    envs = {name: DyanaEnv(RES, episodes="test-1k", obs=name) for name in VIEWS if name != "full"}
    action = np.concatenate([[0.0, 2.0, 4.0], np.full(15, 0.2)]).astype(np.float32)
    seen = {name: [env.reset(seed=SEED)[0], env.step(action)[0]] for name, env in envs.items()}
    truth = [full.reset(seed=SEED)[0], full.step(action)[0]]
    for k, obs in enumerate(truth):
        state = np.concatenate([obs["palm_pose"], obs["joint_angles"], obs["joint_poses"], obs["keypoints"],
                                [np.float32(obs["timestamp"])]])
        assert state.dtype == np.float32 and state.shape == (STATE_WIDTH,)
        np.testing.assert_array_equal(state_vector(obs), state)
        np.testing.assert_array_equal(seen["image"][k], obs["image"])
        np.testing.assert_array_equal(seen["state"][k], state)
        np.testing.assert_array_equal(seen["both"][k]["image"], obs["image"])
        np.testing.assert_array_equal(seen["both"][k]["state"], state)
        for name, env in envs.items():
            assert seen[name][k] in env.observation_space, name
    assert envs["image"].observation_space.shape == (RES, RES, 3)
    assert envs["state"].observation_space.shape == (STATE_WIDTH,)
    assert set(envs["both"].observation_space.spaces) == {"image", "state"}


def test_normalized_actions_map_minus_one_and_one_onto_the_real_bounds():
    env = DyanaEnv(RES, episodes="test-1k", normalize_actions=True)
    assert env.action_space == gymnasium.spaces.Box(-1.0, 1.0, (18,), np.float32)
    obs, _ = env.reset(seed=SEED)
    bounds = np.concatenate([PALM_LOW, JOINT_LOWER]), np.concatenate([PALM_HIGH, JOINT_UPPER])
    for value, palm, joints in ((-1.0, PALM_LOW, JOINT_LOWER), (1.0, PALM_HIGH, JOINT_UPPER), (5.0, PALM_HIGH, JOINT_UPPER),
                                (0.0, (PALM_LOW + PALM_HIGH) / 2, (JOINT_LOWER + JOINT_UPPER) / 2)):
        action = np.full(18, value, dtype=np.float32)
        target = np.clip(absolute_action(action), *bounds)
        np.testing.assert_allclose(target[:3], palm, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(target[3:], joints, rtol=1e-6, atol=1e-6)
        start = np.concatenate([obs["palm_pose"][:3], obs["joint_angles"]]).astype(np.float64)
        obs, _, terminated, truncated, _ = env.step(action)  # the hand heads there, within the body's limits
        reached = np.concatenate([obs["palm_pose"][:3], obs["joint_angles"]]).astype(np.float64)
        assert np.linalg.norm(reached[:3] - target[:3]) < np.linalg.norm(start[:3] - target[:3])
        assert np.all(np.abs(reached[3:] - target[3:]) <= np.abs(start[3:] - target[3:]) + 1e-6)
        if terminated or truncated:  # the joints at their upper limits complete the grasp
            obs, _ = env.reset(seed=SEED)
    frame = env.current_frame
    with pytest.raises(PolicyError, match="NaN"):
        env.step(np.full(18, np.nan))
    assert env.current_frame == frame


@pytest.mark.parametrize("options, message", [
    ({"obs": "rgb"}, "obs must be one of 'full', 'image', 'state', 'both', got 'rgb'"),
    ({"obs": None}, "obs must be one of .* got None"),
    ({"normalize_actions": "yes"}, "normalize_actions must be True or False, got 'yes'"),
    ({"episodes": "no-such-slice"}, "no-such-slice"),
])
def test_bad_options_name_the_argument(options, message):
    with pytest.raises(DyanaError, match=message):
        gymnasium.make(ENV_ID, resolution=RES, **options)


def test_the_recorder_needs_the_full_observation_and_real_actions():
    for options in ({"obs": "image"}, {"normalize_actions": True}):
        with pytest.raises(DyanaError, match=r"RecordEpisode needs DyanaEnv\(obs='full', normalize_actions=False\)"):
            RecordEpisode(DyanaEnv(RES, **options))


def test_gymnasium_check_env_gives_no_warning_with_the_learner_options():
    from gymnasium.utils.env_checker import check_env

    env = learner_env()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert [str(w.message) for w in caught] == []


def test_async_vector_env_with_its_defaults():
    """``AsyncVectorEnv`` of two plain ``gymnasium.make("Dyana/Grasp-v0")``: shared memory
    and the default start method, the default view being fixed-shape Boxes."""
    vec = gymnasium.vector.AsyncVectorEnv([plain_env, plain_env])
    try:
        obs, _ = vec.reset(seed=SEED)
        assert obs["image"].shape == (2, 224, 224, 3) and obs["state"].shape == (2, STATE_WIDTH)
        action = np.zeros((2, 18), dtype=np.float32)
        after, *_ = vec.step(action)
    finally:
        vec.close()
    single = plain_env()
    for k in range(2):  # each sub-environment is the single one seeded SEED + k
        first, _ = single.reset(seed=SEED + k)
        then = single.step(action[k])[0]
        for key in ("image", "state"):
            np.testing.assert_array_equal(obs[key][k], first[key])
            np.testing.assert_array_equal(after[key][k], then[key])


def ppo_learns(env: gymnasium.Env, steps: int) -> None:
    """PPO's ``MultiInputPolicy`` (SB3 wraps the env in a DummyVecEnv) learns ``steps`` steps on it."""
    from stable_baselines3 import PPO

    model = PPO("MultiInputPolicy", env, n_steps=steps, batch_size=steps, n_epochs=1, seed=0, device="cpu")
    model.learn(steps)
    assert model.num_timesteps == steps
    action, _ = model.predict(env.reset(seed=SEED)[0], deterministic=True)
    assert env.action_space.contains(action)


@pytest.mark.torch
def test_ppo_learns_on_the_registered_env_with_only_a_resolution():
    """Before: a TypeError in DummyVecEnv (the full dict's observe window has no fixed shape)."""
    pytest.importorskip("stable_baselines3")
    ppo_learns(gymnasium.make(ENV_ID, resolution=RES), 8)


@pytest.mark.torch
@pytest.mark.slow(cover="tests/pipeline/test_env_learners.py::test_ppo_learns_on_the_registered_env_with_only_a_resolution")
def test_ppo_learns_on_the_plain_registered_env():
    """``gymnasium.make("Dyana/Grasp-v0")`` with no options at all (224 px: about 6 s)."""
    pytest.importorskip("stable_baselines3")
    ppo_learns(gymnasium.make(ENV_ID), 8)


@pytest.mark.torch
def test_stable_baselines3_checks_every_view_with_no_wrapper():
    """SB3's check_env takes every view as it is (silently). PPO learning on the default
    view is test_ppo_learns_on_the_registered_env_with_only_a_resolution (and, under -m slow,
    docs/guides/your-policy.md's Stable-Baselines3 block)."""
    pytest.importorskip("torch")
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env

    for obs in ("image", "state", "both"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(gymnasium.make(ENV_ID, resolution=RES, obs=obs, normalize_actions=True))
        assert [str(w.message) for w in caught] == [], obs


@pytest.fixture(scope="module")
def gymnasium_029(tmp_path_factory) -> Path:
    """A Python with Gymnasium 0.29.1 (the last release that loads plugins on import) in a
    venv of its own that sees this checkout and this interpreter's packages behind it."""
    venv = tmp_path_factory.mktemp("g29")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    install = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps",
                              "gymnasium==0.29.1", "farama-notifications", "cloudpickle"],
                             capture_output=True, text=True, timeout=300)
    if install.returncode != 0:
        pytest.skip(f"gymnasium 0.29.1 is not installable here: {install.stderr.strip()[-200:]}")
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    root = __file__.rsplit("/tests/", 1)[0]
    (Path(site) / "zz_dyana.pth").write_text(f"{root}\n{sysconfig.get_paths()['purelib']}\n")
    return python


CHECK_IN_FRESH_GYMNASIUM = """
import json, sys, warnings
import gymnasium
from gymnasium.utils.env_checker import check_env

out = {"version": gymnasium.__version__}
for env_id in ("Dyana/Grasp-v0", "Dyana/GraspFull-v0"):
    env = gymnasium.make(env_id, resolution=64)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    out[env_id] = [str(w.message) for w in caught]
print(json.dumps(out))
"""


def test_plain_make_and_check_env_in_a_fresh_gymnasium_0_29_interpreter(gymnasium_029):
    """``gymnasium.make("Dyana/Grasp-v0")`` works without importing Dyana (the entry point),
    and Gymnasium's own ``check_env`` passes silently; on the full observation's id, with
    only its advice to normalise the action space."""
    result = subprocess.run([str(gymnasium_029), "-c", CHECK_IN_FRESH_GYMNASIUM], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    out = json.loads(result.stdout.splitlines()[-1])
    assert out["version"] == "0.29.1"
    assert out["Dyana/Grasp-v0"] == []
    full = out["Dyana/GraspFull-v0"]
    assert len(full) == 1 and "symmetric and normalized" in full[0], full


#: Dyana imported first: its own ``import gymnasium`` runs the plugins, Dyana's included.
DYANA_FIRST = """
import json, sys
import {module}
import gymnasium

env = gymnasium.make("Dyana/Grasp-v0", resolution=40, obs="state")
obs, _ = env.reset(seed=2)
print(json.dumps({{"version": gymnasium.__version__, "shape": obs.shape}}))
"""


@pytest.mark.parametrize("module", ["pipeline.loop.env", "pipeline.loop.actions", "pipeline.cli"])
def test_dyana_imported_before_gymnasium_0_29(gymnasium_029, module):
    """The way ``pipeline eval`` starts: a Dyana module whose imports reach Gymnasium, which
    then calls Dyana's entry point while that module is still importing."""
    result = subprocess.run([str(gymnasium_029), "-c", DYANA_FIRST.format(module=module)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert json.loads(result.stdout.splitlines()[-1]) == {"version": "0.29.1", "shape": [STATE_WIDTH]}
