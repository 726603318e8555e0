"""No lookup: nothing a policy receives identifies its episode, and a held-out split drawn
from a private seed (`pipeline eval --test-seed`) cannot be regenerated, so a policy that
looks its episode up in the public recipe falls to chance there."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from generators.heldout import HOW_TO_MAKE, MIN_SECRET_CHARS, PRIVATE_SEED, derive
from generators.recipe import spec_for
from pipeline.jobs.evaluate import evaluate
from pipeline.jobs.replay import replay
from pipeline.jobs.verify import verify
from pipeline.loop.rollout import run_episode
from pipeline.loop.wrappers import loop_env
from schemas.errors import SpecError
from scoring.io import load_run
from scoring.report import score_run
from tests.console import run_here
from tests.pipeline.spy_policy import OUT_ENV, SpyPolicy
from tests.pipeline.test_remote import start_server
from tests.pipeline.test_sealed import needs_unshare

BIN = Path(sys.executable).parent
SECRET = "5b0e1c9d27f84a6e93c1d0b8f2a47e65"
OTHER = "c3a9f1e07d2b4c68a5e19f30b7d64c28"
RESOLUTION = 32
LOOKUP = "tests.pipeline.lookup_policy:LookupPolicy"
FORBIDDEN_KEYS = {"episode_id", "episode_index", "slice", "seed", "spec_hash", "spec"}


def _identifiers(spec) -> list[str]:
    return [spec.episode_id, spec.slice, spec.spec_hash, spec.spec_hash[:16], f"{spec.episode_index:06d}"]


def _keys(value) -> set[str]:
    if isinstance(value, dict):
        return set(value) | {k for v in value.values() for k in _keys(v)}
    if isinstance(value, list):
        return {k for v in value for k in _keys(v)}
    return set()


def _check_seen(lines: list[dict], spec) -> None:
    """What a policy saw holds no key or text that names its episode."""
    assert lines and lines[0]["kind"] == "task" and any(line["kind"] == "observation" for line in lines)
    assert lines[0]["value"]["text"] == spec.text  # the task itself did arrive
    for line in lines:
        assert not _keys(line["value"]) & FORBIDDEN_KEYS, line["value"].keys()
        text = json.dumps(line["value"])
        for identifier in _identifiers(spec):
            assert identifier not in text


def test_no_episode_identity_reaches_a_policy_in_process(tmp_path, monkeypatch):
    out = tmp_path / "seen.jsonl"
    monkeypatch.setenv(OUT_ENV, str(out))
    spec = spec_for("test-1k", 7)
    env = loop_env(RESOLUTION)
    try:
        result = run_episode(env, SpyPolicy(), spec)
    finally:
        env.close()
    assert result.ok
    _check_seen([json.loads(line) for line in out.read_text().splitlines()], spec)


def test_no_episode_identity_crosses_the_wire(tmp_path, monkeypatch):
    out = tmp_path / "seen.jsonl"
    monkeypatch.setenv(OUT_ENV, str(out))
    server, url = start_server("tests.pipeline.spy_policy:SpyPolicy")
    try:
        evaluate(url, "test-1k", tmp_path / "run", episodes=1, workers=0, resolution=RESOLUTION, progress=False,
                 summary=False)
    finally:
        server.terminate()
        server.wait(timeout=30)
    _check_seen([json.loads(line) for line in out.read_text().splitlines()], spec_for("test-1k", 0))


def _grasp_contact(run: Path) -> float:
    return score_run(load_run(run)).overall.metrics["S_grasp_contact"]


def _lookup_scores(tmp_path: Path, episodes: int, resolution: int) -> tuple[float, float]:
    common = dict(episodes=episodes, workers=0, resolution=resolution, progress=False, summary=False)
    evaluate(LOOKUP, "test-1k", tmp_path / "public", isolate=False, **common)
    evaluate(LOOKUP, "test-1k", tmp_path / "private", test_seed=SECRET, **common)  # sealed: pipeline.remote.sandbox
    return _grasp_contact(tmp_path / "public"), _grasp_contact(tmp_path / "private")


@needs_unshare
def test_a_lookup_policy_wins_the_public_split_and_falls_to_chance_on_a_private_one(tmp_path):
    public, private = _lookup_scores(tmp_path, 3, RESOLUTION)
    assert public == 100.0
    assert private <= 5.0


@pytest.mark.slow(cover="tests/pipeline/test_no_lookup.py::test_a_lookup_policy_wins_the_public_split_and_falls_to_chance_on_a_private_one")
@needs_unshare
def test_a_lookup_policy_falls_to_chance_on_a_private_split_at_scale(tmp_path):
    public, private = _lookup_scores(tmp_path, 36, 96)  # four episodes of each of the nine cells
    assert public >= 95.0
    assert private <= 5.0


@pytest.mark.parametrize("secret", ["short-secret", "aaaaaaaabbbbbbbbcccc", "has a space in it 0123456789"])
def test_weak_secrets_are_refused_without_echoing_them(secret, tmp_path):
    with pytest.raises(SpecError) as caught:
        evaluate("still", "test-1k", tmp_path / "run", episodes=1, workers=0, test_seed=secret)
    message = str(caught.value)
    assert secret not in message and "secrets.token_hex(16)" in message
    assert not (tmp_path / "run").exists()


def test_a_private_seed_is_for_the_held_out_slices_only(tmp_path):
    with pytest.raises(SpecError, match="held-out test slices"):
        evaluate("still", "linear-fast", tmp_path / "run", episodes=1, workers=0, test_seed=SECRET)


@pytest.fixture(scope="module")
def private_run(tmp_path_factory) -> Path:
    """A run drawn from the private seed, made once for the tests that read it (none writes to it)."""
    run = tmp_path_factory.mktemp("private") / "run"
    evaluate("predictive", "test-1k", run, episodes=4, workers=0, resolution=RESOLUTION, shard_size=2,
             progress=False, summary=False, test_seed=SECRET)
    return run


def test_the_manifest_keeps_a_hash_and_no_seed_and_the_bytes_are_deterministic(private_run, tmp_path):
    run = private_run
    text = (run / "catalog.json").read_text()
    manifest = json.loads(text)
    record = manifest["test_seed"]
    assert set(record) == {"kdf", "n", "r", "p", "salt", "hash", "scheme"} and record["kdf"] == "scrypt"
    assert manifest["seed"] is None
    seed = derive(SECRET, "test-1k")
    assert SECRET not in text and str(seed.generator_seed) not in text
    episodes = pq.read_table(sorted((run / "episodes").glob("*.parquet"))[0]).to_pylist()
    assert {row["seed"] for row in episodes} == {PRIVATE_SEED}
    assert [row["episode_id"] for row in episodes] == ["test-1k:000000", "test-1k:000001"]
    assert all(str(seed.generator_seed) not in json.dumps(row, default=str) for row in episodes)
    again = tmp_path / "again"
    evaluate("predictive", "test-1k", again, episodes=4, workers=0, resolution=RESOLUTION, shard_size=2,
             progress=False, summary=False, test_seed=SECRET)
    assert json.loads((again / "catalog.json").read_text())["hash"] == manifest["hash"]
    other = tmp_path / "other"
    evaluate("predictive", "test-1k", other, episodes=4, workers=0, resolution=RESOLUTION, shard_size=2,
             progress=False, summary=False, test_seed=OTHER)
    assert json.loads((other / "catalog.json").read_text())["test_seed"]["hash"] != record["hash"]


def test_replay_and_verify_need_the_seed(private_run, tmp_path):
    run = private_run
    with pytest.raises(SpecError, match="drawn from a private test seed; replaying it needs that seed"):
        replay(run)
    with pytest.raises(SpecError, match="does not match the one recorded"):
        replay(run, test_seed=OTHER)
    report = replay(run, test_seed=SECRET)
    assert (report.episodes, report.shards) == (4, 2)
    with pytest.raises(SpecError, match="private test seed"):
        verify(run, sample=1)
    assert verify(run, sample=1, test_seed=SECRET).shards_rebuilt == 1
    public = tmp_path / "public"
    evaluate("still", "test-1k", public, episodes=1, workers=0, resolution=RESOLUTION, progress=False, summary=False)
    with pytest.raises(SpecError, match="public seed"):
        replay(public, test_seed=SECRET)


def test_the_cli_takes_the_seed_from_a_file_and_says_one_line_without_it(tmp_path, capsys):
    secret_file = tmp_path / "test-seed.txt"
    secret_file.write_text(SECRET + "\n")
    run = tmp_path / "run"  # made through the API (a CLI eval starts a Dask cluster; the flags are the same)
    evaluate("still", "test-1k", run, episodes=1, workers=0, resolution=RESOLUTION, progress=False, summary=False,
             test_seed=SECRET)
    bare = subprocess.run([str(BIN / "pipeline"), "replay", str(run)], capture_output=True, text=True)
    assert bare.returncode == 2 and len(bare.stderr.strip().splitlines()) == 1
    assert "needs that seed" in bare.stderr and "Traceback" not in bare.stderr
    # the refusals above and below run the console scripts; these run their mains in this process
    wrong = run_here(capsys, "pipeline", "replay", str(run), "--test-seed", OTHER)
    assert wrong.returncode == 2 and "does not match" in wrong.stderr and OTHER not in wrong.stderr
    good = run_here(capsys, "pipeline", "replay", str(run), "--test-seed-file", str(secret_file), "--quiet")
    assert good.returncode == 0, good.stderr
    info = run_here(capsys, "catalog", "info", str(run))
    assert info.returncode == 0 and "seed private (scrypt hash" in info.stdout and SECRET not in info.stdout
    missing = run_here(capsys, "catalog", "verify", str(run), "--test-seed-file", str(tmp_path / "nope"))
    assert missing.returncode == 2 and "--test-seed-file" in missing.stderr and "cannot read it" in missing.stderr
    common = ["--slice", "test-1k", "--episodes", "1", "--resolution", str(RESOLUTION), "--quiet"]
    weak = subprocess.run([str(BIN / "pipeline"), "eval", "--policy", "still", "--out", str(tmp_path / "weak"), *common,
                           "--test-seed", "x" * (MIN_SECRET_CHARS - 1)], capture_output=True, text=True)
    assert weak.returncode == 2 and len(weak.stderr.strip().splitlines()) == 1 and HOW_TO_MAKE in weak.stderr
    assert not (tmp_path / "weak").exists()
