"""``pipeline eval --policy lerobot:PATH`` with a fake LeRobot (tests/pipeline/fake_lerobot.py):
the mapping of Dyana's observation onto the checkpoint's input features, the refusal of
inputs Dyana does not give, and both normalisation styles (0.3.x in the model, 0.4+ in
saved processors). The real LeRobot releases: tests/pipeline/test_lerobot_real.py (opt-in)."""

from __future__ import annotations

import io
import json
import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import catalog  # noqa: E402
from pipeline.jobs.evaluate import evaluate  # noqa: E402
from pipeline.policies.lerobot_checkpoint import configure, make, read_checkpoint  # noqa: E402
from pipeline.policy_registry import kind_of  # noqa: E402
from schemas.errors import PolicyError, SpecError  # noqa: E402
from tests.pipeline import fake_lerobot  # noqa: E402
from tests.pipeline.fake_lerobot import IMAGE_KEY, TARGET, FakePolicy, write_checkpoint  # noqa: E402

RESOLUTION = 64


@pytest.mark.parametrize("processors", [False, True], ids=["0.3-in-model", "0.4-processors"])
def test_a_checkpoint_runs_in_the_loop_with_its_own_normalisation(tmp_path, monkeypatch, processors):
    fake_lerobot.install(monkeypatch, processors=processors)
    folder = write_checkpoint(tmp_path / "train" / "checkpoints" / "last" / "pretrained_model", processors=processors)
    run = tmp_path / "run"
    ref = f"lerobot:{tmp_path / 'train'}"  # a training output folder: its last checkpoint is found
    assert kind_of(ref).name == "lerobot"
    manifest = evaluate(ref, "test-1k", run, episodes=1, workers=0, resolution=RESOLUTION, progress=False,
                        summary=False, stream=io.StringIO())
    config = manifest.extra["lerobot"]
    assert config["checkpoint"] == str(folder) and config["device"] == "cpu"
    assert config["normalisation"] == ("processors" if processors else "model")
    with catalog.open(run) as ds:
        assert ds.episodes[0].status == "ok" and ds.episodes[0].policy.startswith("lerobot-fake-")
        frames = [ds[i] for i in range(len(ds))]
        acting = [f for f in frames if f["phase"] != "observe"]
        first = acting[0]
    # un-normalised: the model's own (0.3) or the saved postprocessor's (0.4)
    np.testing.assert_allclose(first["action"], TARGET.numpy(), rtol=0, atol=1e-6)
    batch = FakePolicy.calls[0]
    assert batch[IMAGE_KEY].shape == (1, 3, 32, 32)  # Dyana's 64 px frame, resized to the declared feature
    # a call per recorded frame but the last: the policy saw that frame's state
    assert len(FakePolicy.calls) == len(frames) - 1
    for call, frame in zip(FakePolicy.calls, frames):
        palm = np.concatenate([frame["palm_pose"], frame["joint_angles"]]).astype(np.float32)
        expected = (palm - fake_lerobot.STATE_MEAN) / fake_lerobot.STATE_STD if processors else palm
        np.testing.assert_allclose(call["observation.state"][0].numpy(), expected, rtol=1e-6, atol=1e-6)
    assert isinstance(batch["task"][0], str) and batch["task"][0]


def test_an_image_only_policy_is_given_no_state(tmp_path, monkeypatch):
    fake_lerobot.install(monkeypatch, processors=False)
    folder = write_checkpoint(tmp_path / "m", processors=False, state=False, size=(64, 64))
    checkpoint = read_checkpoint(str(folder))
    assert checkpoint.inputs() == {"observation.images.ego": IMAGE_KEY} and checkpoint.image_size == (64, 64)
    evaluate(f"lerobot:{folder}", "test-1k", tmp_path / "run", episodes=1, workers=0, resolution=RESOLUTION,
             progress=False, summary=False, stream=io.StringIO())
    assert set(FakePolicy.calls[0]) == {IMAGE_KEY, "task"}


@pytest.mark.parametrize("extra, named", [
    ({"observation.environment_state": {"type": "ENV", "shape": [7]}}, "observation.environment_state: the object's true pose"),
    ({"observation.images.wrist": {"type": "VISUAL", "shape": [3, 32, 32]}}, "a second image observation.images.wrist"),
    ({"observation.velocity": {"type": "STATE", "shape": [6]}}, "observation.velocity: a STATE input of shape [6]"),
])
def test_an_input_dyana_does_not_give_is_refused_before_lerobot_is_imported(tmp_path, extra, named):
    folder = write_checkpoint(tmp_path / "m", processors=True, extra_inputs=extra)
    with pytest.raises(PolicyError, match="the policy takes") as info:
        configure(f"lerobot:{folder}", None)
    assert named in str(info.value) and str(folder) in str(info.value)
    assert "lerobot.policies.factory" not in sys.modules or not hasattr(sys.modules["lerobot.policies.factory"],
                                                                        "FakePolicy")


def test_a_state_of_another_width_and_another_action_are_refused(tmp_path):
    folder = write_checkpoint(tmp_path / "m", processors=False,
                              extra_inputs={"observation.state": {"type": "STATE", "shape": [14]}})
    with pytest.raises(PolicyError, match=r"observation.state: a STATE input of shape \[14\]"):
        read_checkpoint(str(folder))
    folder = write_checkpoint(tmp_path / "n", processors=False)
    config = json.loads((folder / "config.json").read_text())
    config["output_features"]["action"]["shape"] = [7]
    (folder / "config.json").write_text(json.dumps(config))
    with pytest.raises(PolicyError, match="Dyana takes one 'action' of 18"):
        read_checkpoint(str(folder))


@pytest.mark.parametrize("checkpoint_style, installed, says", [
    (True, False, "saved by LeRobot >= 0.4"),
    (False, True, "a LeRobot 0.3 checkpoint"),
])
def test_a_checkpoint_the_installed_lerobot_cannot_normalise_is_refused(tmp_path, monkeypatch, checkpoint_style,
                                                                        installed, says):
    fake_lerobot.install(monkeypatch, processors=installed)
    folder = write_checkpoint(tmp_path / "m", processors=checkpoint_style)
    with pytest.raises(PolicyError, match=says):
        make(f"lerobot:{folder}", {"device": "cpu"})


def test_bad_paths_and_devices_are_one_error(tmp_path):
    with pytest.raises(PolicyError, match="no such checkpoint folder"):
        configure(f"lerobot:{tmp_path / 'nope'}", None)
    with pytest.raises(PolicyError, match="not a LeRobot checkpoint"):
        configure(f"lerobot:{tmp_path}", None)
    folder = write_checkpoint(tmp_path / "m", processors=False)
    with pytest.raises(SpecError, match="--policy-device must be"):
        configure(f"lerobot:{folder}", {"device": "tpu"})
    (folder / "model.safetensors").unlink()
    with pytest.raises(PolicyError, match="no model.safetensors"):
        configure(f"lerobot:{folder}", None)


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True, timeout=120)


def test_the_cli_refuses_a_privileged_input_and_a_stray_device_in_one_line(tmp_path):
    folder = write_checkpoint(tmp_path / "m", processors=True,
                              extra_inputs={"observation.environment_state": {"type": "ENV", "shape": [7]}})
    result = _cli("eval", "--policy", f"lerobot:{folder}", "--episodes", "1", "--out", str(tmp_path / "run"))
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert "observation.environment_state" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()
    result = _cli("eval", "--policy", "still", "--policy-device", "cuda", "--episodes", "1", "--out", str(tmp_path / "r"))
    assert result.returncode != 0 and "--policy-device is for --policy lerobot:PATH only" in result.stderr


def test_without_lerobot_installed_the_cli_says_how_to_install_it(tmp_path):
    try:
        import lerobot  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("lerobot is installed here")
    folder = write_checkpoint(tmp_path / "m", processors=True)
    result = _cli("eval", "--policy", f"lerobot:{folder}", "--episodes", "1", "--out", str(tmp_path / "run"))
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert "needs LeRobot in this Python" in result.stderr and "pip install" in result.stderr
