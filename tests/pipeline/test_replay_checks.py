"""What `pipeline replay` and `catalog verify` re-derive beyond the frames (issue 26):
the episodes table's status, policy and privileged columns, the manifest's keys, and no
file in a data folder that the manifest does not list; scoring refuses a run missing
its first shard even with a re-hashed and re-sealed manifest."""

from __future__ import annotations

import json
import shutil

import pytest

from catalog.store.manifest import Manifest, load_manifest, write_manifest
from pipeline.jobs.evaluate import evaluate
from pipeline.jobs.replay import replay
from pipeline.jobs.verify import verify
from schemas.errors import ReplayMismatch, ShardError
from scoring.io import load_run
from tests.console import run_here

from .tamper import copy_of, reseal, rewrite_episodes, set_column

RESOLUTION = 32


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "oracle"
    evaluate("oracle", "test-1k", out, episodes=3, workers=0, resolution=RESOLUTION, shard_size=2, progress=False,
             summary=False)
    return out


@pytest.fixture
def copy(run, tmp_path):
    return copy_of(run, tmp_path)


@pytest.mark.parametrize("key, value", [("policy", "predictive"), ("privileged", False), ("deadline_s", 30.0),
                                        ("code", {"version": "0.1.0", "commit": "f" * 40})])
def test_a_hand_edited_manifest_key_fails_replay_and_verify_naming_it(copy, key, value, capsys):
    path = copy / "catalog.json"
    data = json.loads(path.read_text())
    data[key] = value
    path.write_text(json.dumps(data, sort_keys=True, indent=2) + "\n")
    message = f"{path}: edited after it was written (changed: {key};"
    for check in (replay, verify):
        with pytest.raises(ShardError) as info:
            check(copy)
        assert str(info.value).startswith(message)
    if key == "policy":
        for command in (("pipeline", "replay", str(copy)), ("catalog", "verify", str(copy), "--quiet")):
            done = run_here(capsys, *command)
            code, err = done.returncode, done.stderr
            assert code != 0 and err.count("\n") == 1 and message in err, err


@pytest.mark.parametrize("column, value", [("status", "error"), ("policy", "predictive"), ("privileged", False)])
def test_a_rewritten_episodes_column_is_named_by_replay(copy, column, value):
    def mutate(table):
        table = set_column(table, column, 1, value)
        return set_column(table, "error", 1, "frame 9: made up") if column == "status" else table

    rewrite_episodes(copy, 0, mutate)  # the episodes table alone (its MCAP still says otherwise)
    with pytest.raises(ReplayMismatch, match=f"episode 1 .*episodes table, column {column}: recorded") as info:
        replay(copy)
    assert (info.value.episode, info.value.column, info.value.file) == (1, column, "episodes/000000-000001.parquet")
    with pytest.raises(ReplayMismatch, match=f"column {column}"):
        verify(copy)  # a run's verify re-executes it through replay


@pytest.mark.parametrize("column, value", [("status", "error"), ("policy", "predictive"), ("privileged", False)])
def test_a_run_written_with_a_false_column_by_dyanas_own_writer_is_named_by_replay(tmp_path, monkeypatch, column, value):
    """The whole shard (episodes table and MCAP) written by the shard writer with one
    episode's column false, hashed and sealed: only re-deriving the column can tell."""
    from catalog.tables.shard import ShardWriter

    add = ShardWriter.add_episode

    def lying(self, spec, frames, images, **options):
        if spec.episode_index == 1:
            options[column] = value
            if column == "status":
                options["error"] = f"frame {frames.num_frames - 1}: made up"
        add(self, spec, frames, images, **options)

    monkeypatch.setattr(ShardWriter, "add_episode", lying)
    evaluate("oracle", "test-1k", tmp_path / "run", episodes=2, workers=0, resolution=RESOLUTION, shard_size=2,
             progress=False, summary=False)
    monkeypatch.undo()
    with pytest.raises(ReplayMismatch, match=f"episode 1 .*episodes table, column {column}: recorded") as info:
        replay(tmp_path / "run")
    assert (info.value.episode, info.value.column) == (1, column)


def test_a_run_re_sealed_as_non_privileged_is_refused_by_replay(copy):
    rewrite_episodes(copy, 0, lambda t: set_column(set_column(t, "privileged", 0, False), "privileged", 1, False))
    rewrite_episodes(copy, 1, lambda t: set_column(t, "privileged", 0, False))
    reseal(copy, privileged=False)
    with pytest.raises(ShardError, match=r"catalog.json: says policy oracle \(privileged False\), but its configuration "
                                         r"makes oracle \(privileged True\)"):
        replay(copy)


@pytest.mark.parametrize("name", ["000099-000099.parquet", ".hidden", "notes.txt"])
def test_a_stray_file_in_a_data_folder_is_named_by_replay_and_verify(copy, name, capsys):
    stray = copy / "frames" / name
    shutil.copy(copy / "frames" / "000002-000002.parquet", stray)
    for check in (replay, verify):
        with pytest.raises(ShardError, match=f"{stray}: not listed in catalog.json"):
            check(copy)
    if name == "notes.txt":
        done = run_here(capsys, "catalog", "verify", str(copy), "--quiet")
        code, err = done.returncode, done.stderr
        assert code == 2 and err.count("\n") == 1, err
        assert f"frames/{name}: not listed in catalog.json" in err


def test_scoring_refuses_a_run_whose_first_shard_was_removed_and_re_sealed(copy, capsys):
    manifest = load_manifest(copy)
    first = manifest.shards[0]
    for record in first.files.values():
        (copy / record.path).unlink()
    rest = Manifest.create(manifest.slice, manifest.seed, manifest.settings, manifest.shards[1:], code=manifest.code,
                           extra=manifest.extra, stats=manifest.stats)
    write_manifest(copy, rest)
    assert load_manifest(copy).episodes == 1  # the seal and the hash hold: only completeness can tell
    with pytest.raises(ShardError, match=r"episodes 0-1 are missing"):
        load_run(copy)
    done = run_here(capsys, "scoring", "eval", str(copy))
    code, err = done.returncode, done.stderr
    assert code != 0 and "episodes 0-1 are missing" in err and "Traceback" not in err


def test_a_run_from_before_the_hand_body_is_scored_but_not_re_executed(copy):
    """A run records its hand model; one recorded before the hand was a body (no
    settings.hand_model) would re-execute to other states under the body's limits, so replay
    and verify refuse it in one line naming the commit that replays it, and scoring reads it."""
    from schemas.versions import HAND_MODEL, POSE_HAND_COMMIT

    manifest = load_manifest(copy)
    assert manifest.settings["hand_model"] == HAND_MODEL  # what a run records today
    older = {k: v for k, v in manifest.settings.items() if k != "hand_model"}
    write_manifest(copy, Manifest.create(manifest.slice, manifest.seed, older, manifest.shards, code=manifest.code,
                                         extra=manifest.extra, stats=manifest.stats, versions=manifest.versions))
    for check in (replay, verify):
        with pytest.raises(ShardError, match=f"a run recorded before the hand was a body.*commit {POSE_HAND_COMMIT}"):
            check(copy)
    assert len(load_run(copy).episode_index) == 3
