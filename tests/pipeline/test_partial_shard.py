"""An interrupted shard's finished episodes (catalog.tables.partial): staged exactly, refused
when damaged or another job's, taken by the resumed build or eval, which then writes the
bytes of an uninterrupted run; the staging folder never outlives the job."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import pipeline.jobs.evaluate as evaluate_module
import pipeline.stages.record as record_module
from catalog.store.manifest import load_manifest
from catalog.tables.integrity import verify_files
from catalog.tables.partial import MAX_STAGED_BYTES, PARTIAL_DIR, PartialShard, StagedEpisode
from generators.recipe import spec_for
from pipeline.jobs.build import build
from pipeline.jobs.evaluate import evaluate
from pipeline.stages.episode import episode
from tests.shard_files import shard_bytes

SLICE = "linear-fast"
RESOLUTION = 48
BUILD = dict(episodes=6, resolution=RESOLUTION, shard_size=4, workers=0)


def _folder_bytes(folder: Path) -> dict[str, bytes]:
    """Every shard file, the manifest and the statistics."""
    files = shard_bytes(folder)
    for name in ("catalog.json", "stats.json"):
        files[name] = (folder / name).read_bytes()
    return files


def _episode(index: int = 0) -> StagedEpisode:
    spec = spec_for(SLICE, index)
    images = [bytes([index, k]) * (k + 3) for k in range(spec.num_frames)]
    return StagedEpisode(spec, episode(spec), images, {"status": "ok", "audit": [{"x": 0.1}]})


def test_a_staged_episode_loads_back_exactly(tmp_path):
    staged = _episode()
    shard = PartialShard(tmp_path, 0, 4, "job")
    assert shard.load(staged.spec) is None
    shard.save(staged.spec, staged)
    held = shard.load(staged.spec)
    assert held is not None and held.spec.to_json() == staged.spec.to_json()
    assert held.images == staged.images and held.info == staged.info
    for name in ("phase", "object_pose", "palm_pose", "action", "grasp_angles", "palm_distance"):
        mine, back = getattr(staged.frames, name), getattr(held.frames, name)
        assert back.dtype == mine.dtype and back.shape == mine.shape and back.tobytes() == mine.tobytes()
    assert held.frames.obstacle_clearance is None
    shard.remove()
    assert not shard.folder.exists()


def test_a_damaged_or_foreign_staged_file_is_refused_and_removed(tmp_path):
    staged, other = _episode(0), _episode(1)
    shard = PartialShard(tmp_path, 0, 4, "job")
    path = shard.path(0)

    def refused() -> bool:
        return shard.load(staged.spec) is None and not path.exists()

    shard.save(staged.spec, staged)
    data = bytearray(path.read_bytes())
    data[-100] ^= 1
    path.write_bytes(bytes(data))
    assert refused()  # one flipped bit: the checksum fails
    shard.save(staged.spec, staged)
    path.write_bytes(path.read_bytes()[:-10])
    assert refused()  # cut short
    PartialShard(tmp_path, 0, 4, "another job").save(staged.spec, staged)
    assert refused()  # another job's key
    shard.save(other.spec, other)
    os.replace(shard.path(1), path)
    assert refused()  # another episode's file under this index
    path.write_bytes(b"not an episode")
    assert refused()
    with open(path, "wb") as handle:  # a planted huge file (sparse): deleted unread, nothing allocated
        handle.truncate(MAX_STAGED_BYTES + 1)
    assert refused()


def _hooked_episode(monkeypatch, stop_at: int | None) -> list[int]:
    """Count the episodes the build computes; raise KeyboardInterrupt (Ctrl-C) when it starts ``stop_at``."""
    computed: list[int] = []

    def counted(spec):
        if spec.episode_index == stop_at:
            raise KeyboardInterrupt
        computed.append(spec.episode_index)
        return episode(spec)

    monkeypatch.setattr(record_module, "episode", counted)
    return computed


@pytest.fixture(scope="module")
def fresh(tmp_path_factory):
    """The uninterrupted build the resumed ones must equal (read only): its manifest and folder."""
    out = tmp_path_factory.mktemp("fresh")
    return build(SLICE, out, progress=False, **BUILD), out / SLICE


def test_an_interrupted_build_resumes_mid_shard_to_the_same_bytes(tmp_path, monkeypatch, capsys, fresh):
    reference, fresh_dir = fresh
    computed = _hooked_episode(monkeypatch, stop_at=2)
    with pytest.raises(KeyboardInterrupt):
        build(SLICE, tmp_path / "out", progress=False, **BUILD)
    slice_dir = tmp_path / "out" / SLICE
    assert computed == [0, 1] and not (slice_dir / "catalog.json").exists()
    assert sorted(p.name for p in (slice_dir / PARTIAL_DIR / "000000-000004").iterdir()) == ["000000.episode", "000001.episode"]

    computed = _hooked_episode(monkeypatch, stop_at=None)
    capsys.readouterr()
    resumed = build(SLICE, tmp_path / "out", progress=True, **BUILD)
    assert computed == [2, 3, 4, 5]  # episodes 0 and 1 were taken from the interrupted shard
    assert "shard 0-3: 2 of its 4 episodes taken from the interrupted run" in capsys.readouterr().err
    assert resumed.hash == reference.hash
    assert _folder_bytes(slice_dir) == _folder_bytes(fresh_dir)
    assert not (slice_dir / PARTIAL_DIR).exists()
    verify_files(slice_dir)


def test_a_damaged_staged_episode_is_computed_again_and_overwrite_clears_them(tmp_path, monkeypatch, fresh):
    reference, fresh_dir = fresh
    _hooked_episode(monkeypatch, stop_at=3)
    with pytest.raises(KeyboardInterrupt):
        build(SLICE, tmp_path / "out", progress=False, **BUILD)
    staging = tmp_path / "out" / SLICE / PARTIAL_DIR / "000000-000004"
    damaged = staging / "000001.episode"
    data = bytearray(damaged.read_bytes())
    data[len(data) // 2] ^= 0x10
    damaged.write_bytes(bytes(data))
    computed = _hooked_episode(monkeypatch, stop_at=None)
    assert build(SLICE, tmp_path / "out", progress=False, **BUILD).hash == reference.hash
    assert computed == [1, 3, 4, 5]  # 0 and 2 taken, the damaged 1 computed again
    assert _folder_bytes(tmp_path / "out" / SLICE) == _folder_bytes(fresh_dir)

    _hooked_episode(monkeypatch, stop_at=2)
    with pytest.raises(KeyboardInterrupt):
        build(SLICE, tmp_path / "again", progress=False, **BUILD)
    computed = _hooked_episode(monkeypatch, stop_at=None)
    build(SLICE, tmp_path / "again", progress=False, overwrite=True, **BUILD)
    assert computed == [0, 1, 2, 3, 4, 5]  # --overwrite starts over: nothing staged is taken
    assert not (tmp_path / "again" / SLICE / PARTIAL_DIR).exists()


def _interrupted_at(monkeypatch, index: int) -> tuple[list[int], list[int]]:
    """The eval's episodes rolled out from now on (``ran``), and a Ctrl-C at episode
    ``stop[0]`` (set it to -1 to let a rerun finish)."""
    real, ran, stop = evaluate_module.run_episode, [], [index]

    def counted(env, policy, spec, deadline_s):
        if spec.episode_index == stop[0]:
            raise KeyboardInterrupt
        ran.append(spec.episode_index)
        return real(env, policy, spec, deadline_s)

    monkeypatch.setattr(evaluate_module, "run_episode", counted)
    return ran, stop


def test_an_interrupted_evaluation_resumes_mid_shard_to_the_same_bytes(tmp_path, monkeypatch):
    settings = dict(episodes=3, resolution=RESOLUTION, shard_size=3, workers=0, progress=False, summary=False)
    reference = evaluate("oracle", "test-1k", tmp_path / "fresh", **settings)
    ran, stop = _interrupted_at(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        evaluate("oracle", "test-1k", tmp_path / "run", **settings)
    assert ran == [0, 1]
    ran.clear()
    stop[0] = -1
    resumed = evaluate("oracle", "test-1k", tmp_path / "run", **settings)
    assert ran == [2]
    assert resumed.hash == reference.hash
    assert _folder_bytes(tmp_path / "run") == _folder_bytes(tmp_path / "fresh")
    assert not (tmp_path / "run" / PARTIAL_DIR).exists()


def test_a_user_policy_s_interrupted_shard_runs_again_whole(tmp_path, monkeypatch):
    """A user's policy may carry state from episode to episode: its episodes are not staged,
    so a resumed shard starts from its first episode with a fresh policy, as before."""
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "counting.py").write_text("import numpy as np\n\nclass Counting:\n    name = 'counting'\n"
                                          "    action_horizon = 1\n    privileged = False\n    seen = 0\n"
                                          "    def reset(self, task):\n        Counting.seen += 1\n"
                                          "    def act(self, obs):\n        return np.concatenate([obs['palm_pose'][:3] + "
                                          "0.01 * Counting.seen, obs['joint_angles']]).astype(np.float32)\n")
    settings = dict(episodes=3, resolution=RESOLUTION, shard_size=3, workers=0, progress=False, summary=False,
                    isolate=False)
    ran, stop = _interrupted_at(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        evaluate("counting:Counting", "test-1k", tmp_path / "run", **settings)
    assert ran == [0, 1] and not (tmp_path / "run" / PARTIAL_DIR).exists()
    ran.clear()
    stop[0] = -1
    evaluate("counting:Counting", "test-1k", tmp_path / "run", **settings)
    assert ran == [0, 1, 2]


@pytest.mark.slow(cover="tests/pipeline/test_partial_shard.py::test_an_interrupted_build_resumes_mid_shard_to_the_same_bytes")
def test_a_killed_two_worker_build_resumes_its_shards_in_flight(tmp_path):
    """SIGKILL of a build on two Dask workers once each worker staged an episode of its
    shard (two shards in flight, staged by the workers themselves), then the same command."""
    cmd = [sys.executable, "-m", "pipeline.cli", "build", "--slice", SLICE, "--episodes", "8", "--shard-size", "4",
           "--resolution", str(RESOLUTION), "--workers", "2", "--out", str(tmp_path / "out")]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    staging = tmp_path / "out" / SLICE / PARTIAL_DIR
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:
        shards = [d for d in staging.glob("*") if any(d.glob("*.episode"))] if staging.is_dir() else []
        if len(shards) == 2:
            break
        time.sleep(0.02)
    else:
        proc.kill()
        pytest.fail("the build staged no episode of two shards in time")
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    resumed = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert resumed.stderr.count("episodes taken from the interrupted run") == 2
    fresh = build(SLICE, tmp_path / "fresh", episodes=8, resolution=RESOLUTION, shard_size=4, workers=0, progress=False)
    assert load_manifest(tmp_path / "out" / SLICE).hash == fresh.hash
    assert _folder_bytes(tmp_path / "out" / SLICE) == _folder_bytes(tmp_path / "fresh" / SLICE)
    assert sorted(p.name for p in (tmp_path / "out" / SLICE).rglob(".*")) == [".lock"]


def test_frames_arrays_survive_any_float_bits(tmp_path):
    """NaN payloads and negative zeros come back bit for bit (the bytes are stored, not values)."""
    staged = _episode()
    odd = staged.frames.palm_distance.copy()
    odd[:3] = np.frombuffer(np.array([0x7FC00123, 0x80000000, 0xFF800000], dtype=np.uint32).tobytes(), dtype=np.float32)
    frames = staged.frames.__class__(**{**staged.frames.__dict__, "palm_distance": odd})
    shard = PartialShard(tmp_path, 0, 4, "job")
    shard.save(staged.spec, StagedEpisode(staged.spec, frames, staged.images))
    held = shard.load(staged.spec)
    assert held is not None and held.frames.palm_distance.tobytes() == odd.tobytes()


def test_an_eval_episode_is_staged_with_its_counts_and_audit(tmp_path):
    """What an eval task stages of a rollout comes back as the same result; counts it cannot
    read make it computed again (None), not a failed shard."""
    from pipeline.jobs.staged import held_result, staged_episode
    from pipeline.loop.rollout import RolloutResult

    base = _episode()
    result = RolloutResult(base.spec, base.frames, base.images, "error", "hung", 7, 3, False, True, 0.25)
    shard = PartialShard(tmp_path, 0, 4, "job")
    shard.save(base.spec, staged_episode(result, [{"episode_id": base.spec.episode_id, "text": "a"}]))
    held = held_result(shard.load(base.spec))
    assert held is not None
    back, audit = held
    assert (back.status, back.error, back.steps, back.calls, back.localized, back.grasped, back.policy_s) == \
        ("error", "hung", 7, 3, False, True, 0.25)
    assert back.images == base.images and audit == [{"episode_id": base.spec.episode_id, "text": "a"}]
    assert held_result(None) is None
    assert held_result(StagedEpisode(base.spec, base.frames, base.images, {"status": "ok"})) is None
