"""Dyana in LeRobot's evaluation without LeRobot installed (:mod:`pipeline.envhub`): the
environment ``lerobot-eval --env.type=dyana`` steps (LeRobot's keys, the instruction,
``is_success`` as scoring eval's headline), its recording (the bytes of ``pipeline eval
--policy lerobot:PATH``, driven here the way LeRobot's rollout drives it, with the fake
LeRobot of tests/pipeline/fake_lerobot.py) and ``pipeline serve --policy lerobot:PATH`` in
both protocols. The real LeRobot releases: tests/pipeline/test_lerobot_real.py (opt-in)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from catalog.loader.lerobot_names import CAMERA, IMAGE_KEY, IMAGES_PREFIX, STATE_KEY
from catalog.store.manifest import load_manifest
from generators.recipe import spec_for
from pipeline.envhub import env as envhub
from pipeline.envhub.grasp import LeRobotGrasp, command_line_policy, make_vector_env
from pipeline.jobs.evaluate import evaluate
from pipeline.loop.wrappers import loop_env
from schemas.errors import SpecError
from scoring.io import load_run
from scoring.metrics import failed
from scoring.registry import success
from scoring.report import score_run
from tests.pipeline.in_thread import served
from tests.shard_files import shard_bytes

RESOLUTION = 32
EPISODES = dict(resolution=RESOLUTION, workers=0, progress=False, summary=False)


def test_observations_are_under_lerobots_keys_and_the_task_is_the_episodes_instruction():
    assert IMAGES_PREFIX + CAMERA == IMAGE_KEY  # what LeRobot's preprocess_observation makes of pixels[camera]
    envs = make_vector_env(2, resolution=RESOLUTION, record="")
    try:
        obs, info = envs.reset(seed=[1000, 1001])  # lerobot-eval's default seed: episodes 0 and 1
        assert obs["pixels"][CAMERA].shape == (2, RESOLUTION, RESOLUTION, 3) and obs["pixels"][CAMERA].dtype == np.uint8
        assert obs["agent_pos"].shape == (2, 21) and obs["agent_pos"].dtype == np.float32
        assert envs.call("task_description") == (spec_for("test-1k", 0).text, spec_for("test-1k", 1).text)
        assert not info["is_success"].any()
        plain = loop_env(RESOLUTION)
        seen, _ = plain.reset(options={"spec": spec_for("test-1k", 1)})
        plain.close()
        np.testing.assert_array_equal(obs["pixels"][CAMERA][1], seen["image"])
        np.testing.assert_array_equal(obs["agent_pos"][1], np.concatenate([seen["palm_pose"], seen["joint_angles"]]))
        assert all(frame.shape == (RESOLUTION, RESOLUTION, 3) for frame in envs.call("render"))
    finally:
        envs.close()


def _episode_actions(run: Path) -> dict[int, np.ndarray]:
    """The actions each episode of a run issued (its acting frames but the last)."""
    import catalog

    out: dict[int, list[np.ndarray]] = {}
    with catalog.open(run) as ds:
        for i in range(len(ds)):
            item = ds[i]
            if item["phase"] != "observe":
                out.setdefault(int(item["episode_index"]), []).append(item["action"])
    return {k: np.stack(v[:-1]) for k, v in out.items()}


def test_is_success_is_scoring_evals_headline_success(tmp_path):
    """The oracle's actions, replayed in the LeRobot environment: each episode's final
    ``is_success`` is its S_grasp_contact as ``scoring eval`` reads the oracle's run."""
    evaluate("oracle", "test-1k", tmp_path / "oracle", episodes=3, **EPISODES)
    data = load_run(tmp_path / "oracle")
    expected = success(score_run(data).per_episode, ~failed(data.error, data.min_clearance, True)).tolist()
    assert True in expected, "the oracle grasps some of them, so both answers are seen"
    env = LeRobotGrasp(resolution=RESOLUTION, record="")
    try:
        for index, actions in _episode_actions(tmp_path / "oracle").items():
            env.reset(seed=1000 + index)
            for k, action in enumerate(actions):
                _, _, terminated, truncated, info = env.step(action)
                assert (terminated or truncated) == (k == len(actions) - 1)
            assert info["is_success"] == expected[index], index
    finally:
        env.close()


def test_the_command_line_names_the_policy():
    assert command_line_policy(["--policy.path=/ck", "--env.type=dyana", "--policy.device", "cuda"]) == ("/ck", "cuda")
    assert command_line_policy(["--env.type=dyana"]) == (None, None)


def _checkpoint(folder: Path) -> Path:
    """A checkpoint folder the recorder can name (it reads config.json and hashes the model)."""
    from tests.pipeline.fake_lerobot import write_checkpoint

    return write_checkpoint(folder, processors=True, size=(RESOLUTION, RESOLUTION))


def test_recording_needs_a_checkpoint_an_empty_folder_and_the_first_episodes(tmp_path, monkeypatch):
    pytest.importorskip("torch")
    monkeypatch.setattr("sys.argv", ["lerobot-eval", "--env.type=dyana"])
    with pytest.raises(SpecError, match="--policy.path"):
        LeRobotGrasp(resolution=RESOLUTION, record=str(tmp_path / "run"))
    checkpoint = _checkpoint(tmp_path / "ckpt")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(SpecError, match="holds files"):
        LeRobotGrasp(resolution=RESOLUTION, record=str(tmp_path / "full"), policy=str(checkpoint))
    with pytest.raises(SpecError, match="--env.overwrite must be true or false, got 'yes'"):
        LeRobotGrasp(resolution=RESOLUTION, record=str(tmp_path / "run"), policy=str(checkpoint), overwrite="yes")
    env = LeRobotGrasp(resolution=RESOLUTION, record=str(tmp_path / "run"), policy=str(checkpoint))
    env.reset(seed=1005)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.zeros(18, np.float32))
        done = terminated or truncated
    with pytest.raises(SpecError, match=r"recorded episodes \[5\].*first N episodes"):
        env.close()
    assert not (tmp_path / "run").exists() and not list(tmp_path.glob(".run.episodes-*"))


def _lerobot_rollout(envs, policy, seeds: list[int]) -> list[bool]:
    """What LeRobot's rollout does with a batch (lerobot/scripts/lerobot_eval.py): reset the
    policy and the seeded environments, then step until all are done, giving the policy the
    observation as ``preprocess_observation`` keys it and the task as ``add_envs_task``."""
    import torch

    policy.reset()
    obs, _ = envs.reset(seed=seeds)
    done, successes = np.zeros(len(seeds), bool), [False] * len(seeds)
    while not done.all():
        image = torch.from_numpy(obs["pixels"][CAMERA]).permute(0, 3, 1, 2).contiguous().float() / 255
        batch = {IMAGE_KEY: image, STATE_KEY: torch.from_numpy(obs["agent_pos"]).float(),
                 "task": list(envs.call("task_description"))}
        with torch.inference_mode():
            action = policy.select_action(batch)
        obs, _, terminated, truncated, info = envs.step(action.numpy().astype(np.float32))
        if "final_info" in info:
            for k in np.flatnonzero(info["final_info"]["_is_success"]):
                successes[k] = successes[k] or (not done[k] and bool(info["final_info"]["is_success"][k]))
        done |= terminated | truncated
    return successes


def test_a_lerobot_style_rollout_records_the_bytes_of_pipeline_eval(tmp_path, monkeypatch):
    pytest.importorskip("torch")
    from pipeline.policies.lerobot_checkpoint import load, read_checkpoint
    from tests.pipeline import fake_lerobot

    fake_lerobot.install(monkeypatch, processors=True)
    checkpoint = _checkpoint(tmp_path / "ckpt")
    ref = f"lerobot:{checkpoint}"
    reference = evaluate(ref, "test-1k", tmp_path / "eval", episodes=3, **EPISODES)
    monkeypatch.setattr("sys.argv", ["lerobot-eval", f"--policy.path={checkpoint}", "--env.type=dyana"])
    with pytest.raises(SpecError, match="holds files"):
        envhub.make_env(1, record=str(tmp_path / "eval"), resolution=RESOLUTION)
    envs = envhub.make_env(1, record=str(tmp_path / "lerobot"), resolution=RESOLUTION)["dyana"][0]
    policy = load(read_checkpoint(str(checkpoint)), "cpu")
    stdout = io.StringIO()
    monkeypatch.setattr("sys.stdout", stdout)
    for seed in (1000, 1001, 1002):  # lerobot-eval --eval.batch_size=1 --eval.n_episodes=3
        _lerobot_rollout(envs, policy, [seed])
    envs.close()  # the run is written now
    assert "evaluated lerobot-fake-" in stdout.getvalue()
    recorded = load_manifest(tmp_path / "lerobot")
    assert shard_bytes(tmp_path / "lerobot") == shard_bytes(tmp_path / "eval")
    assert recorded.hash == reference.hash and recorded.extra == reference.extra


@pytest.mark.parametrize("wire", ["dyana", "openpi"])
def test_serve_serves_a_lerobot_checkpoint_in_both_protocols(tmp_path, monkeypatch, wire):
    pytest.importorskip("torch")
    from pipeline.policy_registry import serving_factory
    from pipeline.remote.serve import checked_factory
    from pipeline.remote.wires import wire_for
    from tests.pipeline import fake_lerobot

    fake_lerobot.install(monkeypatch, processors=True)
    ref = f"lerobot:{_checkpoint(tmp_path / 'ckpt')}"
    chosen = wire_for(wire)
    factory = checked_factory(serving_factory(ref, {"policy_device": "cpu"}), chosen, ref)
    with served(factory, wire=chosen) as served_url:
        url = ("openpi:" if wire == "openpi" else "") + served_url
        local = evaluate(ref, "test-1k", tmp_path / "local", episodes=2, **EPISODES)
        remote = evaluate(url, "test-1k", tmp_path / "remote", episodes=2, **EPISODES)
    assert shard_bytes(tmp_path / "remote") == shard_bytes(tmp_path / "local")
    assert remote.extra["policy"] == local.extra["policy"]


def test_serve_refuses_a_kind_it_cannot_serve_in_one_line():
    from pipeline.policy_registry import serving_factory

    with pytest.raises(SpecError, match="pipeline serve serves .*lerobot:PATH.*, not 'vlm:http://h/v1'"):
        serving_factory("vlm:http://h/v1", {})
