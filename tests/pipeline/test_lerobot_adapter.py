"""LeRobot-style torch policies in the closed loop: the adapter, and the learned baseline
trained for a few steps on two episodes (the tiny version of benchmarks/train_chunk_cnn.py)."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import catalog  # noqa: E402
from generators.recipe import spec_for  # noqa: E402
from pipeline.jobs.evaluate import evaluate  # noqa: E402
from pipeline.loop.env import horizon  # noqa: E402
from pipeline.loop.rollout import task_for  # noqa: E402
from pipeline.loop.wrappers import loop_env  # noqa: E402
from pipeline.policies.lerobot_adapter import LeRobotAdapter  # noqa: E402
from tests.pipeline.lerobot_like import TARGET, PointPolicy  # noqa: E402

RESOLUTION = 64


def _first_act(adapter: LeRobotAdapter, spec) -> dict:
    env = loop_env(resolution=RESOLUTION)
    try:
        obs, _ = env.reset(options={"spec": spec})
        adapter.reset(task_for(spec, RESOLUTION, False, horizon(spec)))
        return adapter.batch(obs), obs
    finally:
        env.close()


def test_the_batch_is_keyed_and_scaled_as_the_keyed_loader_gives_training_data():
    spec = spec_for("test-1k", 3)
    batch, obs = _first_act(LeRobotAdapter(PointPolicy(), "point"), spec)
    image = batch["observation.images.ego"]
    assert image.shape == (1, 3, RESOLUTION, RESOLUTION) and image.dtype == torch.float32
    expected = torch.from_numpy(obs["image"].transpose(2, 0, 1).astype(np.float32) / np.float32(255))
    assert torch.equal(image[0], expected)
    state = np.concatenate([obs["palm_pose"], obs["joint_angles"]])
    assert torch.equal(batch["observation.state"][0], torch.from_numpy(state.astype(np.float32)))
    assert batch["task"] == [spec.text]


@pytest.mark.parametrize("index, pads", [(3, [False, False, False]), (0, [True, True, False])])
def test_history_starts_from_the_observe_window_and_pads_like_the_loader(index, pads):
    spec = spec_for("test-1k", index)
    assert (spec.observe_frames >= 2) == (pads[0] is False)
    batch, obs = _first_act(LeRobotAdapter(PointPolicy(), "point", history=2, image_size=(32, 32)), spec)
    assert batch["observation.images.ego"].shape == (1, 3, 3, 32, 32)
    assert batch["observation.images.ego_is_pad"].tolist() == [pads]
    assert batch["observation.state"].shape == (1, 3, 21)


def test_a_lerobot_policy_runs_through_pipeline_eval_in_its_own_process(tmp_path):
    run = tmp_path / "run"
    evaluate("tests.pipeline.lerobot_like:make", "test-1k", run, episodes=2, workers=1, resolution=RESOLUTION,
             progress=False, summary=False, stream=io.StringIO())
    with catalog.open(run) as ds:
        acting = [ds[i] for i in range(len(ds)) if ds[i]["phase"] != "observe"]
        assert {e.status for e in ds.episodes} == {"ok"}
    np.testing.assert_array_equal(acting[0]["action"], TARGET.numpy())


@pytest.mark.slow(cover="tests/pipeline/test_lerobot_adapter.py::test_a_lerobot_policy_runs_through_pipeline_eval_in_its_own_process")
def test_a_wrong_action_shape_fails_its_episode_not_the_run(tmp_path):
    run = tmp_path / "run"
    evaluate("tests.pipeline.lerobot_like:make_wrong", "test-1k", run, episodes=2, workers=1, resolution=RESOLUTION,
             progress=False, summary=False, stream=io.StringIO())
    with catalog.open(run) as ds:
        assert [e.status for e in ds.episodes] == ["error", "error"]


@pytest.mark.slow(cover="tests/pipeline/test_lerobot_adapter.py::test_the_batch_is_keyed_and_scaled_as_the_keyed_loader_gives_training_data")
def test_the_baseline_trains_saves_loads_and_runs_in_the_loop(tmp_path, monkeypatch):
    from pipeline.jobs.build import build
    from pipeline.policies.chunk_cnn import ChunkCNNConfig, ChunkCNNPolicy
    from pipeline.policies.chunk_cnn_training import train

    build("harmonic-fast", tmp_path / "data", episodes=2, shard_size=2, resolution=RESOLUTION, workers=1,
          progress=False)
    config = ChunkCNNConfig(image_size=(32, 32), chunk=4, n_action_steps=2, keypoints=8, hidden=32)
    policy, record = train([str(tmp_path / "data" / "harmonic-fast")], config, epochs=1, batch_size=8, workers=0,
                           max_steps=3)
    assert record["steps"] == 3 and record["training_frames"] > 0 and record["episodes"] == 2
    folder = policy.save(tmp_path / "ckpt", record)
    loaded = ChunkCNNPolicy.load(folder)
    with catalog.open(str(tmp_path / "data" / "harmonic-fast"), keys="lerobot", history=config.history,
                      action_horizon=config.chunk, resize=config.image_size) as ds:
        item = ds[len(ds) // 2]
    batch = {k: torch.from_numpy(np.asarray(item[k]))[None] for k in ("observation.images.ego", "observation.state")}
    assert torch.equal(policy.predict_chunk(batch), loaded.predict_chunk(batch))
    assert json.loads((folder / "config.json").read_text())["record"]["steps"] == 3
    monkeypatch.setenv("DYANA_CHUNK_CNN", str(folder))
    run = tmp_path / "run"
    evaluate("pipeline.policies.chunk_cnn:pretrained", "test-1k", run, episodes=1, workers=1, resolution=RESOLUTION,
             progress=False, summary=False, stream=io.StringIO())
    with catalog.open(run) as ds:
        assert ds.episodes[0].status == "ok" and ds.episodes[0].policy == "chunk_cnn"


def test_pretrained_without_a_checkpoint_is_one_clear_error(tmp_path, monkeypatch):
    # An installed wheel has no benchmarks/results/chunk_cnn: one line naming the folder and the fix.
    from pipeline.policies.chunk_cnn import pretrained
    from schemas.errors import PolicyError

    monkeypatch.setenv("DYANA_CHUNK_CNN", str(tmp_path / "nowhere"))
    with pytest.raises(PolicyError, match=r"no checkpoint .* in .*nowhere; set DYANA_CHUNK_CNN$"):
        pretrained()
