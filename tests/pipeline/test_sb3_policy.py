"""``pipeline eval --policy sb3:MODEL.zip``: a Stable-Baselines3 model trained on
``gymnasium.make("Dyana/Grasp-v0")`` scored with the view and action mapping it was trained
with, no wrapper; what the run's manifest records; bad models in one line."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import gymnasium
import numpy as np
import pytest

pytest.importorskip("torch")
sb3 = pytest.importorskip("stable_baselines3")

from generators.recipe import spec_for  # noqa: E402
from pipeline.cli import main  # noqa: E402
from pipeline.loop.env import ENV_ID, FULL_ENV_ID  # noqa: E402
from pipeline.loop.sb3_policy import configure, make, split_ref, view_of  # noqa: E402
from pipeline.loop.views import VIEWS  # noqa: E402
from pipeline.policy_registry import kind_of  # noqa: E402
from schemas.errors import PolicyError, SpecError  # noqa: E402

pytestmark = pytest.mark.torch
RES = 40  # SB3's NatureCNN needs at least 36 px


@pytest.fixture(scope="module")
def ppo_zip(tmp_path_factory) -> Path:
    """A PPO trained for 64 steps on the registered env (only its resolution set), saved."""
    path = tmp_path_factory.mktemp("sb3") / "ppo.zip"
    model = sb3.PPO("MultiInputPolicy", gymnasium.make(ENV_ID, resolution=RES), n_steps=64, batch_size=64,
                    n_epochs=1, seed=0, device="cpu")
    model.learn(64)
    model.save(path)
    return path


def eval_args(ref: str, out: Path) -> list[str]:
    return ["eval", "--policy", ref, "--slice", "test-1k", "--episodes", "2", "--resolution", str(RES), "--out", str(out)]


def test_a_trained_model_is_scored_from_the_command_line_deterministically(ppo_zip, tmp_path):
    """Twice: the same bytes (one hash); the manifest records the zip's sha256 and what the
    model was trained on."""
    for name in "ab":
        assert main([*eval_args(f"sb3:{ppo_zip}", tmp_path / name), "--quiet"]) == 0
    a, b = (json.loads((tmp_path / name / "catalog.json").read_text()) for name in "ab")
    assert a["hash"] == b["hash"] and a["episodes"] == 2
    assert a["sb3"] == {"algo": "PPO", "model": "ppo.zip", "normalize_actions": True, "obs": "both", "resolution": RES,
                        "saved_by": sb3.__version__, "sha256": hashlib.sha256(ppo_zip.read_bytes()).hexdigest()}
    assert a["policy"] == "sb3-ppo-" + a["sb3"]["sha256"][:8]


@pytest.mark.slow(cover="tests/pipeline/test_sb3_policy.py::test_a_trained_model_is_scored_from_the_command_line_deterministically")
def test_python_m_pipeline_cli_in_a_fresh_interpreter_gives_the_same_bytes(ppo_zip, tmp_path):
    """``python -m pipeline.cli eval --policy sb3:...`` as a user runs it (about 8 s: torch's import)."""
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", *eval_args(f"sb3:{ppo_zip}", tmp_path / "a"), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert main([*eval_args(f"sb3:{ppo_zip}", tmp_path / "b"), "--quiet"]) == 0
    a, b = (json.loads((tmp_path / name / "catalog.json").read_text()) for name in "ab")
    assert a["hash"] == b["hash"] and a["sb3"] == b["sb3"]


def test_the_policy_acts_as_the_model_does_in_the_env_it_was_trained_on(ppo_zip):
    """The full observation mapped to the model's view, its [-1, 1] action mapped back to the
    absolute one: stepping the full env with the policy's actions and the learner's env with
    the model's own gives the same observations."""
    policy = make(f"sb3:{ppo_zip}", None)
    model = sb3.PPO.load(ppo_zip, device="cpu")
    full, learner = gymnasium.make(FULL_ENV_ID, resolution=RES), gymnasium.make(ENV_ID, resolution=RES)
    spec = spec_for("test-1k", 2)
    obs, _ = full.reset(options={"spec": spec})
    seen, _ = learner.reset(options={"spec": spec})
    policy.reset({"text": spec.text, "fps": 20, "observe_frames": spec.observe_frames, "horizon": 40,
                  "resolution": RES, "hand": spec.hand})
    for _ in range(3):
        view = VIEWS["both"].show(obs)
        np.testing.assert_array_equal(view["image"], seen["image"])
        np.testing.assert_array_equal(view["state"], seen["state"])
        action, _ = model.predict(seen, deterministic=True)
        obs = full.step(policy.act(obs))[0]
        seen = learner.step(action)[0]
    with pytest.raises(PolicyError, match=f"trained on {RES} px images, the run renders 64 px: pass --resolution {RES}"):
        policy.reset({"text": "", "fps": 20, "observe_frames": 0, "horizon": 1, "resolution": 64, "hand": "right"})


def test_a_run_at_another_resolution_is_one_line_before_it_starts(ppo_zip, tmp_path, capsys):
    args = eval_args(f"sb3:{ppo_zip}", tmp_path / "run")
    args[args.index("--resolution") + 1] = "64"
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"trained on {RES} px images: pass --resolution {RES}" in err
    assert not (tmp_path / "run").exists()


def test_the_view_and_action_mapping_come_from_the_saved_spaces(tmp_path):
    """An untrained PPO on the state view with real actions: recorded as such."""
    path = tmp_path / "state.zip"
    sb3.PPO("MlpPolicy", gymnasium.make(ENV_ID, resolution=RES, obs="state", normalize_actions=False),
            n_steps=64, device="cpu").save(path)
    config = configure(f"sb3:{path}", None)
    assert (config["obs"], config["resolution"], config["normalize_actions"], config["algo"]) == ("state", None, False, "PPO")
    space = gymnasium.spaces.Box(0, 255, (3, RES, RES), np.uint8)  # SB3's transposed image
    assert view_of("m", space) == ("image", RES) and view_of("m", VIEWS["image"].space(RES)) == ("image", RES)
    with pytest.raises(PolicyError, match="none of DyanaEnv's views"):
        view_of("m", gymnasium.spaces.Box(0, 1, (5,), np.float32))


def test_references_and_algorithms():
    assert kind_of("sb3:m.zip").name == "sb3"
    assert split_ref("sb3:m.zip") == (None, "m.zip") and split_ref("sb3:ddpg:m.zip") == ("DDPG", "m.zip")
    assert split_ref("sb3:dir:with/colon.zip") == (None, "dir:with/colon.zip")
    with pytest.raises(SpecError, match="expected sb3:MODEL.zip"):
        split_ref("sb3:")


def test_a_wrong_algorithm_is_refused(ppo_zip):
    with pytest.raises(PolicyError, match="saved by PPO, not SAC"):
        configure(f"sb3:sac:{ppo_zip}", None)


def not_a_model(tmp_path: Path) -> dict[str, tuple[str, str]]:
    junk = tmp_path / "junk.zip"
    junk.write_text("not a zip\n")
    empty = tmp_path / "empty.zip"
    with zipfile.ZipFile(empty, "w") as archive:
        archive.writestr("readme.txt", "hello")
    pendulum = tmp_path / "pendulum.zip"
    sb3.PPO("MlpPolicy", gymnasium.make("Pendulum-v1"), n_steps=64, device="cpu").save(pendulum)
    return {
        "missing": (str(tmp_path / "nope.zip"), "no such Stable-Baselines3 model file"),
        "junk": (str(junk), "not a Stable-Baselines3 model (not a zip file)"),
        "empty": (str(empty), "not a Stable-Baselines3 model (no 'data' in the zip)"),
        "pendulum": (str(pendulum), "is none of DyanaEnv's views"),
    }


def test_a_bad_model_is_one_line_and_exit_2(tmp_path, capsys):
    for name, (path, message) in not_a_model(tmp_path).items():
        code = main(eval_args(f"sb3:{path}", tmp_path / f"run-{name}"))
        err = capsys.readouterr().err
        assert code == 2, name
        assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
        assert not (tmp_path / f"run-{name}" / "catalog.json").exists()


class Reader:
    """A payload in a model's data: unpickling it copies the file ``source`` into ``leak``."""

    def __init__(self, source: Path, leak: Path) -> None:
        self.source, self.leak = str(source), str(leak)

    def __reduce__(self):
        code = (f"try:\n    open({self.leak!r}, 'w').write(open({self.source!r}).read())\n"
                "except OSError:\n    pass\n")
        return exec, (code,)


def with_payload(model: Path, out: Path, payload: Reader) -> Path:
    """``model`` with ``payload`` in its data, as SB3 stores what JSON cannot hold (cloudpickle)."""
    import base64

    import cloudpickle

    with zipfile.ZipFile(model) as src, zipfile.ZipFile(out, "w") as dst:
        for item in src.infolist():
            body = src.read(item.filename)
            if item.filename == "data":
                data = json.loads(body)
                data["extra"] = {":type:": "<class 'NoneType'>",
                                 ":serialized:": base64.b64encode(cloudpickle.dumps(payload)).decode()}
                body = json.dumps(data).encode()
            dst.writestr(item, body)
    return out


from pipeline.remote import sandbox  # noqa: E402

#: Where the machine cannot seal, tests/pipeline/test_sealed.py covers the refusal.
needs_unshare = pytest.mark.skipif(sandbox.unavailable() is not None, reason="cannot seal a policy here")
SECRET = "0f9e8d7c6b5a49382716a5b4c3d2e1f0"


def _secret_folder(tmp_path: Path) -> Path:
    keep = tmp_path / "keep"
    keep.mkdir()
    (keep / "seed.txt").write_text(SECRET + "\n")
    (keep / "canary.txt").write_text("canary\n")
    return keep


@needs_unshare
def test_a_model_runs_code_when_loaded_so_a_private_split_configures_it_sealed(ppo_zip, tmp_path):
    """SB3's ``load`` unpickles what a zip's data holds: a model is code. Here its payload
    copies a file out. Configured in this process it copies the canary (the payload runs);
    configured for a private split (sealed: the secret file reads as nothing, the copy lands
    in the sandbox's scratch) nothing reaches this side, and the configuration is the same."""
    keep, leak = _secret_folder(tmp_path), tmp_path / "leak.txt"
    public = with_payload(ppo_zip, tmp_path / "public.zip", Reader(keep / "canary.txt", leak))
    here = configure(f"sb3:{public}", None)
    assert leak.read_text() == "canary\n"
    leak.unlink()
    private = with_payload(ppo_zip, tmp_path / "private.zip", Reader(keep / "seed.txt", leak))
    seal = sandbox.sealing(kind_of(f"sb3:{private}").sealed_files(f"sb3:{private}"), object(), True,
                           str(keep / "seed.txt"), str(tmp_path / "run"))
    assert seal is not None and seal.shown == (str(private),)
    sealed = sandbox.configured(seal, f"sb3:{private}", None)
    assert not leak.exists()
    assert sealed == {**here, "model": "private.zip", "sha256": hashlib.sha256(private.read_bytes()).hexdigest()}


@needs_unshare
@pytest.mark.slow(cover="tests/pipeline/test_sb3_policy.py::test_a_model_runs_code_when_loaded_so_a_private_split_configures_it_sealed")
def test_a_private_split_plays_a_model_sealed(ppo_zip, tmp_path):
    """End to end: ``pipeline eval --test-seed-file`` of a model whose payload copies the
    secret file out runs and scores, and nothing is copied."""
    keep, leak = _secret_folder(tmp_path), tmp_path / "leak.txt"
    private = with_payload(ppo_zip, tmp_path / "private.zip", Reader(keep / "seed.txt", leak))
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", *eval_args(f"sb3:{private}", tmp_path / "sealed"),
                           "--episodes", "1", "--test-seed-file", str(keep / "seed.txt"), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert not leak.exists() and SECRET not in done.stdout + done.stderr
    manifest = json.loads((tmp_path / "sealed" / "catalog.json").read_text())
    assert manifest["episodes"] == 1 and manifest["sb3"]["sha256"] == hashlib.sha256(private.read_bytes()).hexdigest()


def test_pipeline_serve_serves_a_model(ppo_zip):
    """``pipeline serve --policy sb3:MODEL.zip`` makes the same policy as an eval (what a sealed run serves)."""
    from pipeline.policy_registry import serving_factory

    policy = serving_factory(f"sb3:{ppo_zip}", {})()
    assert policy.name == "sb3-ppo-" + hashlib.sha256(ppo_zip.read_bytes()).hexdigest()[:8]
    with pytest.raises(SpecError, match="--model"):
        serving_factory(f"sb3:{ppo_zip}", {"model": "x"})
