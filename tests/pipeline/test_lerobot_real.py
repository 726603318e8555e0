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
