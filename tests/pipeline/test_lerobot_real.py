"""The training command lines of docs/guides/export-lerobot.md, run with the real LeRobot
releases (opt-in, ``-m lerobot_real``): ACT and Diffusion Policy train on a Dyana export with
each release's own ``lerobot-train``, and the checkpoint runs with ``pipeline eval --policy
lerobot:...``.

The lines are read from the guide (one ``lerobot-train`` block per release and policy, its
``docs-test: skip lerobot X.Y.x: ...`` marker naming the release), so a change to the
guide's flags changes what these tests run. Only the flags in :func:`shrunk` change: the
test's own two-episode export at 96 px, its output folder and a few steps (the point is that
the path works end to end: the checkpoint's features, its normalisation style,
un-normalised actions; not what the policy learns). The default test run checks, without
LeRobot, that every documented line is found and holds those flags.

Each release lives in its own environment made by ``.ci/lerobot-venvs`` under
``$DYANA_LEROBOT_VENVS`` (default ``~/.cache/dyana/lerobot-venvs``), holding that lerobot
and this checkout of Dyana; a release whose environment is missing is skipped, saying so.
LeRobot 0.3.x trains on the v2.1 export, later releases on v3.0.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
from pathlib import Path

import numpy as np
import pytest

import catalog
from catalog.export.lerobot import ExportSettings
from catalog.store.manifest import load_manifest
from pipeline.jobs.export import export
from tests.docs.pages import load

VENVS = Path(os.environ.get("DYANA_LEROBOT_VENVS", Path.home() / ".cache" / "dyana" / "lerobot-venvs"))
RELEASES = ("0.3.2", "0.4.4", "0.6.1")
POLICIES = ("act", "diffusion")
GUIDE = "docs/guides/export-lerobot.md"
#: 96 px: at least Diffusion Policy's 84 px crop in 0.3.x, so no flag but the shrunk ones changes.
RESOLUTION, STEPS = 96, 4


def series(version: str) -> str:
    """``0.4.4`` -> ``0.4``: the guide has one section per minor release."""
    return ".".join(version.split(".")[:2])


def documented(release: str, policy: str) -> tuple[dict[str, str], list[str]]:
    """The environment and argv (``lerobot-train`` first) of the guide's line for LeRobot
    ``release`` (``0.4``) and ``policy``: the one block whose skip marker names the release."""
    found = []
    for block in load(GUIDE).blocks:
        if block.marker is None or not re.match(rf"lerobot {re.escape(release)}\.x:", block.marker.argument):
            continue
        words = shlex.split(block.code.replace("\\\n", " "), comments=True)
        env = {}
        while words and re.fullmatch(r"[A-Z_][A-Z0-9_]*=.*", words[0]):
            name, _, value = words.pop(0).partition("=")
            env[name] = value
        if words[:1] == ["lerobot-train"] and f"--policy.type={policy}" in words:
            found.append((env, words))
    assert len(found) == 1, f"{GUIDE}: {len(found)} lerobot-train lines for LeRobot {release}.x and {policy}, want 1"
    return found[0]


def shrunk(dataset: Path, output: Path) -> dict[str, str]:
    """What the tests change in a documented line, and to what; nothing else changes."""
    return {"--dataset.root": str(dataset), "--output_dir": str(output), "--steps": str(STEPS),
            "--save_freq": str(STEPS), "--log_freq": "1"}


def shrink(argv: list[str], changes: dict[str, str]) -> list[str]:
    """``argv`` with each ``--flag=value`` of ``changes`` given its new value; every one must be there once."""
    out, seen = [], []
    for word in argv:
        flag, equals, _ = word.partition("=")
        if equals and flag in changes:
            seen.append(flag)
            word = f"{flag}={changes[flag]}"
        out.append(word)
    assert sorted(seen) == sorted(changes), f"{GUIDE}: want each of {sorted(changes)} once in {shlex.join(argv)}"
    return out


@pytest.mark.parametrize("policy", POLICIES)
@pytest.mark.parametrize("version", RELEASES)
def test_the_guide_has_an_offline_cpu_training_line_per_release_and_policy(version, policy):
    """Runs by default, without LeRobot: the lines the opt-in tests run are on the page."""
    env, argv = documented(series(version), policy)
    shrink(argv, shrunk(Path("d"), Path("o")))
    assert env == {"HF_HUB_OFFLINE": "1"}
    for flag in ("--policy.device=cpu", "--policy.push_to_hub=false", "--wandb.enable=false"):
        assert flag in argv, (version, policy, flag)
    assert any(word.startswith("--dataset.video_backend=") for word in argv), (version, policy)


def _venv(version: str) -> Path:
    venv = VENVS / f"lerobot-{version}"
    if not (venv / "bin" / "lerobot-train").is_file():
        pytest.skip(f"no LeRobot {version} environment at {venv} (make it with .ci/lerobot-venvs {version})")
    return venv


def _run(argv: list[str], cwd: Path, timeout: float, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_HOME": str(cwd / "hf-home"), "WANDB_MODE": "disabled",
           "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"), **(env or {})}
    result = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    with open(cwd / f"{Path(argv[0]).name}.log", "a", encoding="utf-8") as log:  # kept: lerobot-train's step times
        log.write(f"$ {shlex.join(argv)}\n{result.stdout}{result.stderr}")
    assert result.returncode == 0, f"{' '.join(argv)}\n{result.stdout[-2000:]}\n{result.stderr[-4000:]}"
    return result


def _train(venv: Path, version: str, policy: str, source: Path, tmp_path: Path) -> Path:
    """The guide's line for this release and policy, shrunk, on the release's export format;
    the checkpoint's ``pretrained_model`` folder."""
    env, argv = documented(series(version), policy)
    dataset, train = tmp_path / "dataset", tmp_path / "train"
    export(source, dataset, ExportSettings("lerobot-v2.1" if version.startswith("0.3.") else "lerobot"))
    _run([str(venv / "bin" / argv[0]), *shrink(argv, shrunk(dataset, train))[1:]], tmp_path, 3600, env)
    return train / "checkpoints" / "last" / "pretrained_model"


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    from pipeline.jobs.build import build

    out = tmp_path_factory.mktemp("lerobot-real")
    build("linear-fast", out, episodes=2, shard_size=2, resolution=RESOLUTION, workers=1, progress=False)
    return out / "linear-fast"


@pytest.mark.lerobot_real
@pytest.mark.parametrize("policy", POLICIES)
@pytest.mark.parametrize("version", RELEASES)
def test_the_guides_training_line_trains_and_the_checkpoint_runs_in_the_loop(source, tmp_path, version, policy):
    venv = _venv(version)
    legacy = version.startswith("0.3.")
    model = _train(venv, version, policy, source, tmp_path)
    config = json.loads((model / "config.json").read_text())
    assert config["type"] == policy
    assert set(config["input_features"]) == {"observation.images.ego", "observation.state"}, \
        "the export leaves the object's pose out, so the policy never asks for it"
    assert (model / "policy_preprocessor.json").is_file() != legacy
    run = tmp_path / "run"
    _run([str(venv / "bin" / "pipeline"), "eval", "--policy", f"lerobot:{model.parents[2]}", "--slice", "test-1k",
          "--episodes", "2", "--resolution", str(RESOLUTION), "--workers", "1", "--quiet", "--out", str(run)],
         tmp_path, 3600)
    lerobot = load_manifest(run).extra["lerobot"]
    assert lerobot["type"] == policy and lerobot["device"] == "cpu"
    assert lerobot["normalisation"] == ("model" if legacy else "processors")
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


def _checkpoint(venv: Path, version: str, source: Path, tmp_path: Path) -> Path:
    """A few steps of the guide's ACT line for this release."""
    return _train(venv, version, "act", source, tmp_path)


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


@pytest.mark.lerobot_real
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
    model = _checkpoint(venv, version, source, tmp_path)
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
