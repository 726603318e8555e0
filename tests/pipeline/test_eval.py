"""`pipeline eval` end to end: oracle and still on a few test-1k episodes through the
CLI, scored by `scoring eval`; resume after an interruption; bad input."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pipeline.jobs.engine as engine_module
import pipeline.jobs.evaluate as evaluate_module
from catalog.store.manifest import load_manifest
from catalog.tables.integrity import verify_files
from catalog.tables.shard import ShardWriter, rollout_frame_limit
from generators.recipe import spec_for
from pipeline.jobs.evaluate import evaluate
from pipeline.loop.env import horizon
from pipeline.loop.rollout import run_episode
from pipeline.loop.wrappers import loop_env
from pipeline.policies.base import make_policy
from schemas.errors import ShardError, SpecError
from schemas.frames import EpisodeFrames
from tests.shard_files import shard_names

BIN = Path(sys.executable).parent
RESOLUTION = 48
EPISODES = 6


def _eval_cli(policy: str, out: Path, *extra: str, shard_size: int = 3) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(BIN / "pipeline"), "eval", "--policy", policy, "--slice", "test-1k", "--episodes", str(EPISODES),
         "--resolution", str(RESOLUTION), "--shard-size", str(shard_size), "--workers", "1", "--out", str(out), *extra],
        capture_output=True, text=True, timeout=300,
    )


def _score(run: Path) -> dict:
    result = subprocess.run([str(BIN / "scoring"), "eval", str(run), "--json"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The oracle through the command, as two shards on a Dask worker (each in a worker
    process, with its policy process); still as one shard in this process (the library's
    call: a second command cost its start, and its one shard ran in the command's own
    process anyway). Two Dask workers at once: test_faults.py's CLI run and test_remote.py
    (a second worker here cost 2.5 CPU s and changed no byte)."""
    root = tmp_path_factory.mktemp("eval")
    evaluate("still", "test-1k", root / "still", episodes=EPISODES, resolution=RESOLUTION, shard_size=EPISODES,
             workers=1, progress=False, summary=False)
    return root, {"oracle": _eval_cli("oracle", root / "oracle")}


def test_oracle_localizes_and_grasps_every_episode(runs):
    root, results = runs
    assert results["oracle"].returncode == 0, results["oracle"].stderr
    assert f"evaluated oracle on test-1k: {EPISODES} episodes" in results["oracle"].stdout
    assert f"localized {EPISODES}/{EPISODES} (100.0%), grasped {EPISODES}/{EPISODES} (100.0%)" in results["oracle"].stdout
    report = _score(root / "oracle")
    assert report["episodes"] == EPISODES and report["errors"] == 0
    assert report["metrics"]["S_loc"] == 100.0 and report["metrics"]["S_gra"] == 100.0


def test_still_grasps_nothing(runs):
    root, _ = runs
    report = _score(root / "still")
    assert report["episodes"] == EPISODES and report["errors"] == 0
    assert report["metrics"]["S_gra"] == 0.0


def test_a_run_is_a_verifiable_rollout_folder(runs):
    root, _ = runs
    run = root / "oracle"
    manifest = verify_files(run)
    assert manifest.extra == {"policy": "oracle", "privileged": True, "deadline_s": None}
    assert manifest.slice == "test-1k" and manifest.settings["resolution"] == RESOLUTION
    assert [tuple(s.episodes) for s in manifest.shards] == [(0, 3), (3, 6)]
    assert sorted(p.name for p in run.iterdir()) == [".lock", "catalog.json", "episodes", "frames", "mcap", "stats.json"]


def test_the_oracle_reproduces_the_ground_truth_states(runs):
    """Through the environment, the oracle's frames are the build's frames up to grasp completion."""
    from catalog.tables.parquet_io import column_to_numpy, read_frames
    from pipeline.stages.episode import episode

    root, _ = runs
    manifest = load_manifest(root / "oracle")
    frames = read_frames(root / "oracle" / manifest.shards[0].files["frames"].path)
    index = frames.column("episode_index").to_numpy()
    for i in range(3):
        truth = episode(spec_for("test-1k", i))
        palm = column_to_numpy(frames.column("palm_pose"))[index == i]
        assert np.array_equal(palm, truth.palm_pose[: len(palm)])


class Interrupted(Exception):
    """Stands for a killed run."""


def test_an_evaluation_resumes_after_an_interruption(tmp_path, monkeypatch):
    settings = dict(episodes=4, resolution=RESOLUTION, shard_size=2, workers=0, progress=False, summary=False)
    reference = evaluate("still", "test-1k", tmp_path / "fresh", **settings)

    real, calls, interrupt = evaluate_module.eval_shard, [], [True]

    def interrupted(task, *args):
        calls.append(task.first)
        if task.first == 2 and interrupt and interrupt.pop():
            raise Interrupted
        return real(task, *args)

    monkeypatch.setattr(evaluate_module, "eval_shard", interrupted)
    with pytest.raises(Interrupted):
        evaluate("still", "test-1k", tmp_path / "resumed", **settings)
    assert not (tmp_path / "resumed" / "catalog.json").exists()
    calls.clear()
    resumed = evaluate("still", "test-1k", tmp_path / "resumed", **settings)
    assert calls == [2]  # only the unfinished shard ran again
    assert resumed.hash == reference.hash
    calls.clear()
    evaluate("still", "test-1k", tmp_path / "resumed", **settings)  # complete: nothing to do
    assert calls == []
    with pytest.raises(SpecError, match=r"holds another job \(extra.policy \"still\" -> \"oracle\""):
        evaluate("oracle", "test-1k", tmp_path / "resumed", **settings)


def test_rollout_shards_take_up_to_observe_plus_horizon_frames(tmp_path):
    env = loop_env(resolution=RESOLUTION)
    spec = spec_for("test-1k", 2)
    result = run_episode(env, make_policy("still"), spec, 5.0)
    limit = rollout_frame_limit(spec)
    assert limit == spec.observe_frames + horizon(spec)
    assert result.frames.num_frames == limit > spec.num_frames
    writer = ShardWriter(tmp_path, 2, 3, {"resolution": RESOLUTION}, rollout=True).start()
    writer.add_episode(spec, result.frames, result.images, policy="still", status="ok")
    writer.finish()
    assert all(rollout_frame_limit(spec_for("test-1k", i)) == spec_for("test-1k", i).observe_frames + horizon(spec_for("test-1k", i)) for i in range(50))
    f = result.frames
    longer = EpisodeFrames(
        **{k: np.concatenate([v, v[-1:]]) for k, v in f.__dict__.items() if k != "grasp_angles" and v is not None},
        grasp_angles=f.grasp_angles,
    )
    with ShardWriter(tmp_path / "other", 2, 3, {"resolution": RESOLUTION}, rollout=True) as other:
        with pytest.raises(ShardError, match=f"{limit + 1} frames, more than a rollout's {limit}"):
            other.add_episode(spec, longer, result.images + result.images[-1:], policy="still", status="ok")
        other.abort()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--policy", "nosuch", "--episodes", "1"], "unknown policy 'nosuch'"),
        (["--policy", "still", "--slice", "nowhere", "--episodes", "1"], "nowhere"),
        (["--policy", "still", "--slice", "dyana-12m", "--episodes", "1"], "union"),
        (["--policy", "still", "--episodes", "1001"], "--episodes must be in [1, 1000]"),
        (["--policy", "still", "--deadline", "0"], "expected a number > 0"),
        (["--policy", "no_such_module:fn", "--episodes", "1"], "cannot import module 'no_such_module'"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, message, tmp_path, capsys, monkeypatch):
    """Through the command's entry point in this process (what the console script calls; a
    process each cost its start: test_an_edited_policy_file_is_not_up_to_date's refusal and
    test_build.py's bad input run the command as a process). The command may put the
    current folder on sys.path for a module policy: restored after."""
    from pipeline.cli import main

    monkeypatch.setattr(sys, "path", list(sys.path))
    try:
        code = main(["eval", "--out", str(tmp_path / "run"), *args])
    except SystemExit as exited:  # argparse's own refusal (its usage, then one error line)
        code = exited.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err and "Traceback" not in err, err
    assert not (tmp_path / "run" / "catalog.json").exists()


@pytest.mark.parametrize("command", ["eval", "build"])
def test_an_output_folder_that_cannot_be_made_is_one_line_and_exit_2(command, tmp_path, capsys):
    from pipeline.cli import main

    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder\n")
    args = ["--policy", "still", "--slice", "test-1k"] if command == "eval" else ["--slice", "linear-fast"]
    code = main([command, *args, "--episodes", "1", "--workers", "1", "--quiet", "--out", str(blocker / "run")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith(f"pipeline {command}: ") and "Not a directory" in err and len(err.strip().splitlines()) == 1


def test_a_rerun_with_another_layout_is_refused_and_overwrite_leaves_no_stale_shards(tmp_path):
    settings = dict(resolution=RESOLUTION, workers=0, progress=False, summary=False)
    evaluate("still", "test-1k", tmp_path / "run", episodes=2, shard_size=1, **settings)
    with pytest.raises(SpecError, match="another job .*shards"):
        evaluate("still", "test-1k", tmp_path / "run", episodes=2, shard_size=2, **settings)
    manifest = evaluate("still", "test-1k", tmp_path / "run", episodes=2, shard_size=2, overwrite=True, **settings)
    listed = sorted(f.path for s in manifest.shards for f in s.files.values())
    assert shard_names(tmp_path / "run") == listed
    verify_files(tmp_path / "run")


def test_a_complete_run_by_another_commit_is_reused_after_one_sample_shard(tmp_path, monkeypatch):
    """Rollouts depend on the code, but a commit need not change them: a complete run written
    at another commit has one shard rolled out again and compared (pipeline.jobs.resume),
    then it is up to date, untouched (its catalog.json still names the commit that wrote it)."""
    settings = dict(episodes=1, resolution=RESOLUTION, shard_size=1, workers=0, progress=False, summary=False)
    evaluate("still", "test-1k", tmp_path / "run", **settings)
    real, calls = evaluate_module.eval_shard, []

    def counted(task, *args):
        calls.append(task.first)
        return real(task, *args)

    monkeypatch.setattr(evaluate_module, "eval_shard", counted)
    evaluate("still", "test-1k", tmp_path / "run", **settings)
    assert calls == []
    written = load_manifest(tmp_path / "run")
    monkeypatch.setattr(engine_module, "git_commit", lambda: "0123456789abcdef0123456789abcdef01234567")
    manifest = evaluate("still", "test-1k", tmp_path / "run", **settings)
    assert calls == [0]  # the sample
    assert manifest == written and manifest.code.commit != "0123456789abcdef0123456789abcdef01234567"


def test_a_privileged_policy_is_recorded_and_labelled(runs, capsys):
    """A policy that reads the ground-truth spec is marked in the manifest, in every
    episodes row and in the scores (as an upper bound, not a fair entry)."""
    import pyarrow.parquet as pq

    from scoring.cli import main as scoring_main

    root, _ = runs
    run = root / "oracle"
    manifest = load_manifest(run)
    assert manifest.extra["privileged"] is True
    for shard in manifest.shards:
        assert pq.read_table(run / shard.files["episodes"].path).column("privileged").to_pylist() == [True] * 3
    assert scoring_main(["eval", str(run), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["privileged"] is True and report["label"] == "oracle (privileged)"


#: A process that keeps one core busy for 3 s: a bare interpreter (a spawned
#: multiprocessing child would first import this test module, torch included).
BURNER = "import time\nend = time.monotonic() + 3.0\nwhile time.monotonic() < end:\n    pass\n"


def test_the_same_evaluation_gives_the_same_bytes_under_load(tmp_path):
    """No wall-clock deadline by default: two CPU-burning processes beside the run change
    nothing in its bytes (they once turned slow calls into deadline errors). The runs are
    fresh processes with one BLAS/OpenMP thread each: in this long-lived test process,
    spinning thread pools left by earlier tests (torch) would otherwise make the loaded run
    crawl for minutes, which tests nothing more. The burners stop after 3 s (the loaded
    run's start-up and first acts, where deadlines once bit, run beside them; in a full
    suite run the loaded run otherwise took two minutes; each burning second is a second
    of both cores taken from the rest of the suite). The idle run is this process's (a
    command's start cost more than its episodes): the loaded command must give its bytes."""
    import os

    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    pipeline = str(Path(sys.executable).parent / "pipeline")

    def run(name: str) -> dict:
        args = [pipeline, "eval", "--policy", "predictive", "--episodes", "2", "--resolution", str(RESOLUTION),
                "--shard-size", "2", "--workers", "1", "--quiet", "--out", str(tmp_path / name)]
        result = subprocess.run(args, capture_output=True, text=True, timeout=300, env=env)
        assert result.returncode == 0, result.stderr
        return json.loads((tmp_path / name / "catalog.json").read_text())

    evaluate("predictive", "test-1k", tmp_path / "idle", episodes=2, resolution=RESOLUTION, shard_size=2, workers=0,
             progress=False, summary=False)
    idle = json.loads((tmp_path / "idle" / "catalog.json").read_text())
    burners = [subprocess.Popen([sys.executable, "-c", BURNER]) for _ in range(2)]
    try:
        loaded = run("loaded")
    finally:
        for burner in burners:
            burner.kill()
            burner.wait()
    assert loaded["hash"] == idle["hash"]
    assert loaded["deadline_s"] is None


def test_a_slow_policy_fails_only_with_an_explicit_deadline(tmp_path, monkeypatch):
    """Slowness is not a fault unless the user asks for a deadline (then it is recorded)."""
    from tests.pipeline import faulty_policies

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2]))
    settings = dict(episodes=1, resolution=RESOLUTION, shard_size=1, workers=0, progress=False, summary=False)
    slow = "tests.pipeline.faulty_policies:Slow"
    assert faulty_policies.Slow.delay_s > 0.2
    relaxed = evaluate(slow, "test-1k", tmp_path / "relaxed", **settings)
    strict = evaluate(slow, "test-1k", tmp_path / "strict", deadline_s=0.05, **settings)
    assert relaxed.extra["deadline_s"] is None and strict.extra["deadline_s"] == 0.05
    import pyarrow.parquet as pq

    def statuses(manifest, run):
        return [(r["status"], r["error"]) for s in manifest.shards
                for r in pq.read_table(run / s.files["episodes"].path).to_pylist()]

    assert statuses(relaxed, tmp_path / "relaxed") == [("ok", "")]
    [(status, error)] = statuses(strict, tmp_path / "strict")
    assert status == "error" and "exceeded its deadline of 0.05 s" in error


def test_an_edited_policy_file_is_not_up_to_date(tmp_path, monkeypatch, capsys):
    """The run records its module:callable policy's source sha256: after an edit, a re-run
    into the same folder is refused in one line naming it (not "up to date" with the old
    policy's episodes), and --overwrite runs the new one. The refused re-run is a command
    of its own; the others go through its entry point in this process (a process each cost
    its start; the module and sys.path entry they add are removed after)."""
    from pipeline.cli import main

    (tmp_path / "mine.py").write_text("import numpy as np\n\ndef hold(obs):\n"
                                      "    return np.concatenate([obs['palm_pose'][:3], obs['joint_angles']])\n")
    argv = ["eval", "--policy", "mine:hold", "--slice", "test-1k", "--episodes", "1", "--resolution", "32",
            "--workers", "1", "--out", "run", "--quiet",
            "--in-process"]  # one shard in the pipeline process, no policy child: neither is the subject
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", list(sys.path))
    try:
        assert main(argv) == 0, capsys.readouterr().err
        capsys.readouterr()
        assert main(argv) == 0
        again = capsys.readouterr()
        assert "up to date" in again.out + again.err
        with open(tmp_path / "mine.py", "a") as handle:
            handle.write("# tuned\n")
        edited = subprocess.run([str(BIN / "pipeline"), *argv], cwd=tmp_path, capture_output=True, text=True,
                                timeout=300)
        assert edited.returncode == 2 and edited.stderr.count("\n") == 1 and "Traceback" not in edited.stderr
        assert "holds another job (extra.module" in edited.stderr and "--overwrite" in edited.stderr
        assert main([*argv, "--overwrite"]) == 0, capsys.readouterr().err
    finally:
        sys.modules.pop("mine", None)
    assert load_manifest(tmp_path / "run").extra["module"]["source_sha256"] == hashlib.sha256(
        (tmp_path / "mine.py").read_bytes()).hexdigest()
