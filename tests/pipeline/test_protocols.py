"""Evaluation protocols: latency, real-time mode, perturbations, repeats and disturbances;
each deterministic (except real time), recorded in the manifest and replayable."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from generators.encode import decode_jpeg
from generators.recipe import spec_for
from generators.tracks import evaluate as motion_at
from pipeline.jobs.evaluate import evaluate
from pipeline.jobs.replay import replay
from pipeline.loop.conditions import EvalProtocol
from pipeline.loop.disturb import EARLIEST, LATEST, disturbance_time, disturbed_spec
from pipeline.loop.perturb import PERTURBATIONS, Perturbation, perturbation_rng, psnr
from pipeline.loop.rollout import run_episode
from pipeline.loop.wrappers import loop_env
from pipeline.stages.episode import episode
from schemas.errors import ShardError, SpecError
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

RES = 48
BIN = Path(sys.executable).parent


class Ramp:
    """Moves the palm 0.1 units along +X per frame from rest: latency shows as a shift."""

    name = "ramp"

    def reset(self, task: dict) -> None:
        self.start = None

    def act(self, obs: dict) -> np.ndarray:
        palm = obs["palm_pose"][:3].astype(np.float64)
        if self.start is None:
            self.start = int(obs["frame_index"])
        target = palm.copy()
        target[0] = -3.0 + 0.1 * (int(obs["frame_index"]) - self.start + 1)
        return np.concatenate([target, obs["joint_angles"]]).astype(np.float32)


def test_latency_delays_every_action_by_n_frames_and_the_hand_holds_meanwhile():
    spec = spec_for("test-1k", 3)
    xs = {}
    for n in (0, 3):
        env = loop_env(resolution=RES, protocol=EvalProtocol(latency_frames=n))
        result = run_episode(env, Ramp(), spec)
        xs[n] = result.frames.palm_pose[:, 0].astype(np.float64)
        np.testing.assert_array_equal(result.frames.action[spec.observe_frames:-1, 0],
                                      np.float32(-3.0 + 0.1 * np.arange(1, len(xs[n]) - spec.observe_frames)))
    a = spec.observe_frames
    np.testing.assert_array_equal(xs[3][a : a + 4], xs[0][a])  # rest held for N + 1 frames
    np.testing.assert_array_equal(xs[3][a + 4 : a + 12], xs[0][a + 1 : a + 9])


class Slow(Ramp):
    name = "slow"

    def act(self, obs: dict) -> np.ndarray:
        time.sleep(0.12)
        return super().act(obs)


def test_realtime_mode_turns_inference_time_into_frames():
    spec = spec_for("test-1k", 3)
    env = loop_env(resolution=RES, protocol=EvalProtocol(realtime=True))
    xs = run_episode(env, Slow(), spec).frames.palm_pose[:, 0].astype(np.float64)
    a = spec.observe_frames
    assert env.get_wrapper_attr("delay_frames") >= 3 and np.all(xs[a : a + 4] == xs[a])  # 0.12 s >= 3 frames of 50 ms


@pytest.mark.parametrize("name", sorted(PERTURBATIONS))
def test_each_perturbation_is_seeded_small_and_differs_between_repeats(name):
    spec = spec_for("test-1k", 0)
    frames = episode(spec)
    from pipeline.stages.record import encoded_frames

    clean = decode_jpeg(encoded_frames(spec, frames, 96, 90)[12])
    p = Perturbation(name)
    once = p.apply(clean, perturbation_rng(spec.spec_hash, 0, 12))
    np.testing.assert_array_equal(once, p.apply(clean, perturbation_rng(spec.spec_hash, 0, 12)))
    assert once.shape == clean.shape and once.dtype == np.uint8
    assert psnr(clean, once) > 30.0
    assert not any(np.array_equal(once, p.apply(clean, perturbation_rng(spec.spec_hash, r, 12))) for r in (1, 2, 3))


@pytest.mark.parametrize("text, message", [
    ("blur", r"--perturb must be one of"), ("noise:x", r"strength must be a number"),
    ("noise:100", r"strength must be in \[1, 16\]"), ("jpeg:5", r"strength must be in \[30, 100\]"),
])
def test_bad_perturbations_are_named(text, message):
    with pytest.raises(SpecError, match=message):
        Perturbation.parse(text)


def test_the_policy_sees_the_perturbation_but_the_recording_stays_clean():
    spec = spec_for("test-1k", 1)
    seen = []

    class Watch(Ramp):
        def act(self, obs):
            seen.append(obs["image"].copy())
            return super().act(obs)

    clean_env, noisy_env = loop_env(resolution=RES), loop_env(resolution=RES, protocol=EvalProtocol(perturb=Perturbation("noise")))
    clean = run_episode(clean_env, Watch(), spec)
    first_clean = seen[0]
    seen.clear()
    noisy = run_episode(noisy_env, Watch(), spec)
    assert clean.images == noisy.images
    assert not np.array_equal(first_clean, seen[0]) and np.abs(first_clean.astype(int) - seen[0]).max() <= 2


def test_disturbances_are_seeded_after_the_observe_window_and_path_continuous():
    changed = 0
    for index in range(12):
        spec = spec_for("test-1k", index)
        disturbed, what = disturbed_spec(spec)
        assert disturbed_spec(spec) == (disturbed, what)
        if what is None:
            continue
        changed += 1
        at = disturbance_time(disturbed)
        assert at == pytest.approx(what.frame / FPS) and disturbed.disturbance == what
        assert spec.observe_frames + EARLIEST <= what.frame <= spec.intercept_frame - LATEST
        assert EpisodeSpec.from_json(disturbed.to_json()) == disturbed
        before = motion_at(spec.motion, [at - 1e-9]).position
        after = motion_at(disturbed.motion, [at + 1e-9]).position
        np.testing.assert_allclose(before, after, atol=1e-6)
        late = motion_at(disturbed.motion, [at + 0.3]).position - motion_at(spec.motion, [at + 0.3]).position
        assert np.hypot(*late[0]) > 1e-3
        frames = episode(disturbed)
        assert frames.palm_distance[disturbed.intercept_frame] <= 1e-4
    assert changed >= 10


def test_protocol_runs_are_recorded_deterministic_and_replayable(tmp_path):
    protocol = EvalProtocol(latency_frames=2, perturb=Perturbation("jitter"), disturb=True)
    hashes = []
    for k in range(2):
        manifest = evaluate("predictive", "test-1k", tmp_path / f"run{k}", episodes=3, resolution=RES, workers=0,
                            progress=False, summary=False, protocol=protocol)
        hashes.append(manifest.hash)
    assert hashes[0] == hashes[1]
    settings = json.loads((tmp_path / "run0" / "catalog.json").read_text())["settings"]
    assert settings["protocol"] == {"latency_frames": 2, "realtime": False, "deterministic": True, "perturb": "jitter",
                                    "perturb_strength": 0.5, "repeat": 0, "disturb": True}
    assert replay(tmp_path / "run0").episodes == 3
    plain = evaluate("still", "test-1k", tmp_path / "plain", episodes=1, resolution=RES, workers=0, progress=False,
                     summary=False)
    assert "protocol" not in plain.settings


def test_a_realtime_run_says_so_and_is_not_replayed(tmp_path):
    evaluate("still", "test-1k", tmp_path / "rt", episodes=1, resolution=RES, workers=0, progress=False, summary=False,
             protocol=EvalProtocol(realtime=True))
    assert json.loads((tmp_path / "rt" / "catalog.json").read_text())["settings"]["protocol"]["deterministic"] is False
    with pytest.raises(ShardError, match="real-time run"):
        replay(tmp_path / "rt")


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / args[0]), *args[1:]], capture_output=True, text=True, timeout=300)


@pytest.mark.slow(cover="tests/pipeline/test_protocols.py::test_protocol_runs_are_recorded_deterministic_and_replayable")
def test_repeats_from_the_command_line(tmp_path):
    out = tmp_path / "rob"
    args = ("pipeline", "eval", "--policy", "chase", "--episodes", "2", "--resolution", str(RES), "--workers", "1",
            "--perturb", "noise:3", "--repeats", "2", "--quiet", "--out", str(out))
    result = run(*args)
    assert result.returncode == 0, result.stderr
    index = json.loads((out / "repeats.json").read_text())
    assert [r["path"] for r in index["runs"]] == ["repeat-00", "repeat-01"]
    assert index["protocol"]["perturb"] == "noise" and index["protocol"]["perturb_strength"] == 3.0
    for r, entry in enumerate(index["runs"]):
        manifest = json.loads((out / entry["path"] / "catalog.json").read_text())
        assert manifest["hash"] == entry["hash"] and manifest["settings"]["protocol"]["repeat"] == r
    again = run(*args)
    assert again.returncode == 0 and json.loads((out / "repeats.json").read_text()) == index
    other = run(*args[:-3], "--perturb", "light", "--repeats", "2", "--out", str(out))
    assert other.returncode == 2 and "repeats of another experiment" in other.stderr


@pytest.mark.parametrize("flags, message", [
    (("--latency-frames", "-1"), "--latency-frames must be an integer in [0, 50]"),
    (("--repeats", "100"), "--repeats must be an integer in [2, 64]"),
    (("--perturb", "blur"), "--perturb must be one of"),
    (("--perturb", "noise:"), "--perturb 'noise:': the strength after ':' is empty"),
    (("--perturb", "noise: "), "--perturb 'noise: ': the strength after ':' is empty"),
])
def test_bad_protocol_flags_are_one_line(tmp_path, capsys, flags, message):
    """The first refusal from the console script (a real process's stderr), the others from
    its main in this process: the same parser and checks, without starting Python again."""
    argv = ("pipeline", "eval", "--policy", "still", "--episodes", "1", "--out", str(tmp_path / "x"), *flags)
    if flags[0] == "--latency-frames":
        result = run(*argv)
    else:
        from pipeline.cli import main

        capsys.readouterr()
        code = main(list(argv[1:]))
        out, err = capsys.readouterr()
        result = subprocess.CompletedProcess(argv, code, out, err)
    assert result.returncode == 2 and message in result.stderr and result.stderr.count("\n") == 1
    assert "Traceback" not in result.stderr
