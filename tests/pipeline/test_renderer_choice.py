"""The renderer choice (schemas.renderers): ``window`` (default, dataset 5.0.0) builds the
same bytes with 1 and 2 workers and README command 1's hash; replay, verify and ``catalog
info`` re-execute a folder with the renderer its version names; ``full`` (dataset 3.0.0's,
whose hand 5.0.0 changed) is refused in one line naming the commit that still builds it,
while the env and benchmarks may still draw the full viewport; bad values are refused
before anything is made."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from catalog.store.info import folder_info
from generators.render import Renderer
from pipeline.jobs.build import build
from pipeline.jobs.evaluate import evaluate
from pipeline.jobs.replay import replay
from pipeline.loop.env import DyanaEnv
from schemas.errors import SpecError
from schemas.renderers import SPLAYED_HAND_COMMIT
from tests.shard_files import shard_bytes

SLICE = "linear-fast"
BIN = Path(sys.executable).parent
#: README command 1 (pipeline build --slice linear-fast --episodes 32 --shard-size 16).
README_HASHES = {"window": "134fbe33f926f0d0"}


def _build(out: Path, **options):
    return build(SLICE, out, episodes=4, resolution=224, shard_size=2, progress=False, **options)


@pytest.fixture(scope="module")
def window_build(tmp_path_factory):
    out = tmp_path_factory.mktemp("window")
    return _build(out, workers=0), out / SLICE


@pytest.mark.slow(cover="tests/pipeline/test_build.py::test_two_workers_give_the_same_bytes")
def test_a_window_build_is_the_same_in_process_and_with_two_workers(window_build, tmp_path):
    """The window renderer is the default: test_build.py's two-worker build (at 64 pixels,
    three shards on two workers) compares the same bytes, and catalog.json and stats.json
    too; this repeats it at 224 pixels with a second two-worker cluster (5 CPU s)."""
    manifest, folder = window_build
    assert manifest.settings["dataset_version"] == "5.0.0"
    other = _build(tmp_path, workers=2, renderer="window")
    assert other.hash == manifest.hash
    assert shard_bytes(tmp_path / SLICE) == shard_bytes(folder)


def test_replay_and_info_use_the_renderer_the_folder_records(window_build):
    manifest, folder = window_build
    assert manifest.settings["dataset_version"] == "5.0.0"
    report = replay(folder)
    assert report.frames == manifest.frames
    verdict = folder_info(folder).rebuild
    assert verdict.possible, verdict.reason
    assert "dataset 5.0.0 (--renderer window)" in verdict.reason


def test_full_is_refused_naming_the_commit_that_builds_3_0_0(tmp_path):
    named = rf"renderer 'full' wrote dataset 3\.0\.0, .* commit {SPLAYED_HAND_COMMIT} "
    with pytest.raises(SpecError, match=named):
        build(SLICE, tmp_path / "out", episodes=1, renderer="full", progress=False)
    with pytest.raises(SpecError, match=named):
        evaluate("still", "test-1k", tmp_path / "run", episodes=1, renderer="full", progress=False, summary=False)
    with pytest.raises(SpecError, match=named):
        DyanaEnv(16, renderer="full")
    assert not any(tmp_path.iterdir())
    result = subprocess.run([str(BIN / "pipeline"), "build", "--slice", SLICE, "--out", str(tmp_path / "o"),
                             "--renderer", "full"], capture_output=True, text=True, timeout=120)
    assert result.returncode != 0 and result.stderr.count("\n") == 1 and SPLAYED_HAND_COMMIT in result.stderr
    assert not (tmp_path / "o").exists()


def test_a_rollout_run_records_and_replays_its_renderer(tmp_path):
    run = evaluate("predictive", "test-1k", tmp_path / "w", episodes=1, workers=0, resolution=64, shard_size=1,
                   progress=False, summary=False, renderer="window")
    assert replay(tmp_path / "w").episodes == 1
    assert run.settings["dataset_version"] == "5.0.0"


@pytest.mark.parametrize("bad", ["Full", "", None, 1, "window,full"])
def test_a_bad_renderer_is_refused_before_anything_is_made(bad, tmp_path):
    with pytest.raises(SpecError, match="renderer must be one of"):
        build(SLICE, tmp_path / "out", episodes=1, renderer=bad, progress=False)
    with pytest.raises(SpecError, match="renderer must be one of"):
        evaluate("still", "test-1k", tmp_path / "run", episodes=1, renderer=bad, progress=False, summary=False)
    if bad is not None:  # the env's None is its default renderer
        with pytest.raises(SpecError, match="renderer must be"):
            DyanaEnv(16, renderer=bad)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("command", [["build", "--slice", SLICE], ["eval", "--policy", "still"]])
def test_a_bad_renderer_flag_is_one_line_and_exit_2(command, tmp_path):
    result = subprocess.run([str(BIN / "pipeline"), *command, "--out", str(tmp_path / "o"), "--renderer", "fast"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "--renderer" in result.stderr and "'fast'" in result.stderr
    assert not (tmp_path / "o").exists()


def test_the_env_draws_with_the_renderer_it_is_told():
    from generators.recipe import spec_for

    spec = spec_for("test-1k", 0)
    images = {}
    full = Renderer(64, kind="full")  # the full-viewport draw stays, for benchmarks
    for kind in ("window", full, None):
        env = DyanaEnv(64, renderer=kind)
        try:
            obs, _ = env.reset(options={"spec": spec})
            images["full" if kind is full else kind] = obs["image"]
        finally:
            env.close()
    full.close()
    assert np.array_equal(images[None], images["window"])
    assert images["full"].shape == images["window"].shape


@pytest.mark.slow(cover="tests/pipeline/test_build.py::test_two_workers_give_the_same_bytes")
@pytest.mark.parametrize("kind", sorted(README_HASHES))
def test_readme_command_1_hashes_per_renderer(kind, tmp_path):
    manifest = build(SLICE, tmp_path, episodes=32, shard_size=16, progress=False, renderer=kind)
    assert manifest.hash.startswith(README_HASHES[kind])
