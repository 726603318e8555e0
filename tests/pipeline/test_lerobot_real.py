"""Opt-in (``-m lerobot_real``): the real LeRobot releases train ACT on a Dyana export with
their own ``lerobot-train`` and run the checkpoint with ``pipeline eval --policy lerobot:...``.

Each release lives in its own environment made by ``.ci/lerobot-venvs`` under
``$DYANA_LEROBOT_VENVS`` (default ``~/.cache/dyana/lerobot-venvs``), holding that lerobot
and this checkout of Dyana; a release whose environment is missing is skipped. LeRobot
0.3.x trains on the v2.1 export, later releases on v3.0. A few steps on two episodes at
64 px: the point is that the path works end to end (the checkpoint's features, its
normalisation style, un-normalised actions), not what the policy learns.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import catalog
from catalog.export.lerobot import ExportSettings
from catalog.store.manifest import load_manifest
from pipeline.jobs.export import export

VENVS = Path(os.environ.get("DYANA_LEROBOT_VENVS", Path.home() / ".cache" / "dyana" / "lerobot-venvs"))
RELEASES = ("0.3.2", "0.4.4", "0.6.1")
RESOLUTION, STEPS = 64, 4
pytestmark = pytest.mark.lerobot_real


def _venv(version: str) -> Path:
    venv = VENVS / f"lerobot-{version}"
    if not (venv / "bin" / "lerobot-train").is_file():
        pytest.skip(f"no {venv} (make it with .ci/lerobot-venvs {version})")
    return venv


def _run(argv: list[str], cwd: Path, timeout: float) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_HOME": str(cwd / "hf-home"), "WANDB_MODE": "disabled",
           "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    result = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f"{' '.join(argv)}\n{result.stdout[-2000:]}\n{result.stderr[-4000:]}"
    return result


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    from pipeline.jobs.build import build

    out = tmp_path_factory.mktemp("lerobot-real")
    build("linear-fast", out, episodes=2, shard_size=2, resolution=RESOLUTION, workers=1, progress=False)
    return out / "linear-fast"


@pytest.mark.parametrize("version", RELEASES)
def test_lerobot_trains_act_on_the_export_and_the_checkpoint_runs_in_the_loop(source, tmp_path, version):
    venv = _venv(version)
    legacy = version.startswith("0.3.")
    dataset = tmp_path / "dataset"
    export(source, dataset, ExportSettings("lerobot-v2.1" if legacy else "lerobot"))
    train = tmp_path / "train"
    argv = [str(venv / "bin" / "lerobot-train"), "--dataset.repo_id=dyana/tiny", f"--dataset.root={dataset}",
            "--policy.type=act", "--policy.device=cpu", "--policy.push_to_hub=false",
            "--policy.pretrained_backbone_weights=null", "--policy.chunk_size=10", "--policy.n_action_steps=10",
            "--policy.dim_model=64", "--policy.dim_feedforward=128", "--policy.n_encoder_layers=1",
            "--policy.n_decoder_layers=1", "--batch_size=2", f"--steps={STEPS}", "--num_workers=0",
            f"--save_freq={STEPS}", "--log_freq=1", "--wandb.enable=false", f"--output_dir={train}"]
    if legacy:
        argv.append("--dataset.video_backend=torchcodec")
    _run(argv, tmp_path, 3600)
    model = train / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((model / "config.json").read_text())
    assert set(config["input_features"]) == {"observation.images.ego", "observation.state"}, \
        "the export leaves the object's pose out, so the policy never asks for it"
    assert (model / "policy_preprocessor.json").is_file() != legacy
    run = tmp_path / "run"
    _run([str(venv / "bin" / "pipeline"), "eval", "--policy", f"lerobot:{train}", "--slice", "test-1k",
          "--episodes", "2", "--resolution", str(RESOLUTION), "--workers", "1", "--quiet", "--out", str(run)],
         tmp_path, 1800)
    lerobot = load_manifest(run).extra["lerobot"]
    assert lerobot["normalisation"] == ("model" if legacy else "processors") and lerobot["device"] == "cpu"
    with catalog.open(source) as ds:
        trained = np.stack([ds[i]["action"] for i in range(len(ds))])
    with catalog.open(run) as ds:
        assert [e.status for e in ds.episodes] == ["ok", "ok"]
        acted = np.stack([ds[i]["action"] for i in range(len(ds)) if ds[i]["phase"] != "observe"])
    # un-normalised: the palm targets sit where the training data's do (a normalised output
    # would sit near 0, e.g. palm y 0.40 instead of about 1.56)
    low, high = trained[:, :3].min(axis=0), trained[:, :3].max(axis=0)
    margin = (high - low) + 0.05
    assert np.all(acted[:, :3].mean(axis=0) > low - margin) and np.all(acted[:, :3].mean(axis=0) < high + margin), \
        (acted[:, :3].mean(axis=0), low, high)


# --- lerobot-eval on Dyana and pipeline serve of a checkpoint (issue 40) ------------------

EVAL_RELEASES = ("0.4.4", "0.6.1")


def _checkpoint(venv: Path, source: Path, tmp_path: Path) -> Path:
    """A few ACT steps on the v3.0 export (decoded with PyAV: torchcodec needs FFmpeg's libraries)."""
    dataset, train = tmp_path / "dataset", tmp_path / "train"
    export(source, dataset, ExportSettings("lerobot"))
    _run([str(venv / "bin" / "lerobot-train"), "--dataset.repo_id=dyana/tiny", f"--dataset.root={dataset}",
          "--dataset.video_backend=pyav", "--policy.type=act", "--policy.device=cpu", "--policy.push_to_hub=false",
          "--policy.pretrained_backbone_weights=null", "--policy.chunk_size=10", "--policy.n_action_steps=10",
          "--policy.dim_model=64", "--policy.dim_feedforward=128", "--policy.n_encoder_layers=1",
          "--policy.n_decoder_layers=1", "--batch_size=2", f"--steps={STEPS}", "--num_workers=0",
          f"--save_freq={STEPS}", "--log_freq=1", "--wandb.enable=false", f"--output_dir={train}"], tmp_path, 3600)
    return train / "checkpoints" / "last" / "pretrained_model"


def _serving(venv: Path, argv: list[str], cwd: Path) -> tuple[subprocess.Popen, str]:
    """`pipeline serve --port 0` of the venv; the process and the URL it printed."""
    import re

    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_HOME": str(cwd / "hf-home"),
           "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}  # as _run's: torch's threads change its sums
    proc = subprocess.Popen([str(venv / "bin" / "pipeline"), "serve", "--port", "0", *argv], cwd=cwd, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    for line in proc.stderr:
        found = re.search(r"serving \S+ on (ws://127\.0\.0\.1:\d+)", line)
        if found:
            return proc, found.group(1)
    raise AssertionError(f"pipeline serve exited with {proc.wait()} before listening")


@pytest.mark.parametrize("version", EVAL_RELEASES)
def test_lerobot_eval_runs_dyana_and_records_what_pipeline_eval_records(source, tmp_path, version):
    """``lerobot-eval --env.type=dyana`` on 2 test-1k episodes: LeRobot's success rate is the
    run's S_grasp_contact, and the run it records is ``pipeline eval --policy lerobot:PATH``'s,
    byte for byte; the EnvHub ``env.py`` loads from its folder with LeRobot's hub loader; and
    ``pipeline serve --policy lerobot:PATH`` gives the same bytes over dyana/1 and openpi."""
    from scoring.io import load_run
    from scoring.metrics import failed
    from scoring.registry import success
    from scoring.report import score_run
    from tests.shard_files import shard_bytes

    venv = _venv(version)
    model = _checkpoint(venv, source, tmp_path)
    recorded, evaluated = tmp_path / "lerobot-run", tmp_path / "eval-run"
    result = _run([str(venv / "bin" / "lerobot-eval"), f"--policy.path={model}", "--policy.device=cpu",
                   "--env.type=dyana", "--env.discover_packages_path=pipeline.envhub", f"--env.resolution={RESOLUTION}",
                   f"--env.record={recorded}", "--eval.batch_size=1", "--eval.n_episodes=2",
                   f"--output_dir={tmp_path / 'lerobot-eval'}"], tmp_path, 1800)
    assert "evaluated lerobot-act-" in result.stdout
    _run([str(venv / "bin" / "pipeline"), "eval", "--policy", f"lerobot:{model}", "--slice", "test-1k",
          "--episodes", "2", "--resolution", str(RESOLUTION), "--workers", "1", "--quiet", "--out", str(evaluated)],
         tmp_path, 1800)
    assert shard_bytes(recorded) == shard_bytes(evaluated)
    assert load_manifest(recorded).hash == load_manifest(evaluated).hash
    info = json.loads((tmp_path / "lerobot-eval" / "eval_info.json").read_text())
    data = load_run(recorded)
    headline = success(score_run(data).per_episode, ~failed(data.error, data.min_clearance, True)).tolist()
    assert info["per_task"][0]["metrics"]["successes"] == headline

    env_py = Path(__file__).resolve().parents[2] / "pipeline" / "envhub" / "env.py"
    probe = ("import sys\nfrom lerobot.envs.utils import _import_hub_module, _call_make_env, _normalize_hub_result, "
             "preprocess_observation\n"
             "envs = _normalize_hub_result(_call_make_env(_import_hub_module(sys.argv[1], 'dyana/envhub'), n_envs=2, "
             "use_async_envs=False, cfg=None))\n"
             "env = envs['dyana'][0]\nobs, _ = env.reset(seed=[1000, 1001])\n"
             "batch = {**preprocess_observation(obs), 'task': list(env.call('task_description'))}  # as lerobot-eval\n"
             "print(sorted(batch), tuple(batch['observation.state'].shape), batch['task'][0])\nenv.close()\n")
    shown = _run([str(venv / "bin" / "python"), "-c", probe, str(env_py)], tmp_path, 600).stdout
    assert "['observation.images.ego', 'observation.state', 'task'] (2, 21) Catch the paper roll" in shown, shown

    for wire, scheme in (("dyana", ""), ("openpi", "openpi:")):
        proc, url = _serving(venv, ["--policy", f"lerobot:{model}", "--protocol", wire], tmp_path)
        try:
            served = tmp_path / f"served-{wire}"
            _run([str(venv / "bin" / "pipeline"), "eval", "--policy", scheme + url, "--slice", "test-1k", "--episodes",
                  "2", "--resolution", str(RESOLUTION), "--workers", "1", "--quiet", "--out", str(served)], tmp_path, 1800)
        finally:
            proc.terminate()
            proc.wait(timeout=60)
        assert shard_bytes(served) == shard_bytes(evaluated), wire
