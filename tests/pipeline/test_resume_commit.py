"""Resume and "up to date" across a commit that changes no byte (one rule for a folder and
an object store; one sample shard rebuilt and compared first), a commit that changes bytes
refused, and statistics merged from the workers' partial statistics without reading a
shard back."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from catalog.store.manifest import CodeInfo, load_manifest, write_manifest
from catalog.tables.stats import STATS_NAME, compute_stats
from pipeline.jobs import build as build_module
from pipeline.jobs import engine, object_store, runner
from pipeline.jobs.build import build_job
from pipeline.jobs.state import STATE_FILE
from schemas.errors import ShardError
from tests.s3_server import s3_server

SLICE = "linear-fast"
OTHER = "f" * 40  # a commit that is not this checkout's (a docs-only commit, say)


def _build(out: Path, **kwargs):
    options = {"episodes": 5, "shard_size": 2, "resolution": 16, "workers": 0, "progress": False} | kwargs
    return build_job(SLICE, out, **options)


def _counting(monkeypatch) -> list[int]:
    """Count the shard tasks a build runs (its workers and its sample check alike)."""
    calls: list[int] = []
    real = build_module.build_shard

    def counted(task, settings, sink):
        calls.append(task.first)
        return real(task, settings, sink)

    monkeypatch.setattr(build_module, "build_shard", counted)
    return calls


def _interrupted(out: Path, monkeypatch) -> Path:
    """A build killed (Ctrl-C) at its second shard; its state then says another commit wrote
    the first, as a docs-only commit pulled between the kill and the rerun would."""
    real = build_module.build_shard

    def dies(task, settings, sink):
        if task.first == 2:
            raise KeyboardInterrupt
        return real(task, settings, sink)

    with monkeypatch.context() as patch:
        patch.setattr(build_module, "build_shard", dies)
        with pytest.raises(KeyboardInterrupt):
            _build(out)
    state_path = out / SLICE / STATE_FILE
    state = json.loads(state_path.read_text())
    assert len(state["shards"]) == 1
    state["code"]["commit"] = OTHER
    state_path.write_text(json.dumps(state))
    return out / SLICE


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted build."""
    return _build(tmp_path_factory.mktemp("reference")).manifest


def _no_read_back(monkeypatch) -> None:
    """The driver may not read a shard to compute the statistics."""
    def refused(*args, **kwargs):
        raise AssertionError("the driver read a shard back for the statistics")

    monkeypatch.setattr(runner, "shard_partial", refused)


def _stats_are_the_folders(folder: Path) -> None:
    """stats.json is byte for byte what one pass over the finished folder gives."""
    assert (folder / STATS_NAME).read_text() == compute_stats(folder).to_json()


def test_an_interrupted_build_keeps_its_shards_across_a_commit(reference, tmp_path, monkeypatch, capsys):
    folder = _interrupted(tmp_path, monkeypatch)
    assert json.loads((folder / STATE_FILE).read_text())["kept"][0]["partial_stats"]["frames"] > 0
    calls = _counting(monkeypatch)
    _no_read_back(monkeypatch)  # the kept shard's partial statistics come from the state
    resumed = _build(tmp_path, progress=True)
    assert (resumed.shards_resumed, resumed.shards_run) == (1, 2)
    assert calls == [0, 2, 4]  # the sample (the one kept shard), then the two shards left
    assert resumed.manifest.hash == reference.hash
    assert resumed.manifest.code.commit == engine.git_commit()  # the code that finished the folder
    err = capsys.readouterr().err
    assert f"written by commit {OTHER[:12]}" in err and "rebuilding shard 0-1 to check" in err
    _stats_are_the_folders(folder)


def test_a_state_without_partial_statistics_reads_its_kept_shards(reference, tmp_path, monkeypatch):
    """A state written before partial statistics were kept: the kept shard is read once."""
    folder = _interrupted(tmp_path, monkeypatch)
    state = json.loads((folder / STATE_FILE).read_text())
    del state["kept"]
    (folder / STATE_FILE).write_text(json.dumps(state))
    resumed = _build(tmp_path)
    assert resumed.shards_resumed == 1 and resumed.manifest.hash == reference.hash


@pytest.mark.parametrize("recorded", [OTHER, None])
def test_a_finished_build_of_another_commit_is_up_to_date(reference, tmp_path, monkeypatch, recorded):
    _build(tmp_path)
    folder = tmp_path / SLICE
    manifest = load_manifest(folder)
    write_manifest(folder, dataclasses.replace(manifest, code=CodeInfo(manifest.code.version, recorded)))
    before = (folder / "catalog.json").read_bytes()
    calls = _counting(monkeypatch)
    again = _build(tmp_path)
    assert again.up_to_date and calls == [4]  # only the sample: the shortest shard, 4-4
    assert (folder / "catalog.json").read_bytes() == before  # it still names the code that wrote it


def test_an_unknown_commit_samples_too(tmp_path, monkeypatch):
    """Installed without a checkout (no commit): every kept shard is sampled first."""
    _build(tmp_path)
    monkeypatch.setattr(engine, "git_commit", lambda: None)
    calls = _counting(monkeypatch)
    assert _build(tmp_path).up_to_date and calls == [4]


def test_a_commit_that_changes_bytes_is_refused_at_resume(tmp_path, monkeypatch):
    _interrupted(tmp_path, monkeypatch)
    monkeypatch.setattr("catalog.tables.mcap_writer.LIBRARY", "dyana/changed")  # the MCAP header's bytes
    with pytest.raises(ShardError) as refused:
        _build(tmp_path)
    message = str(refused.value)
    assert "\n" not in message
    assert f"/{SLICE}/mcap/" in message and ": shard 0-1 rebuilt by commit " in message
    assert f"differs from what commit {OTHER[:12]} wrote" in message
    assert "without a dataset-version bump" in message and "--overwrite" in message
    rebuilt = _build(tmp_path, overwrite=True)  # on purpose: every shard rebuilt by this code
    assert (rebuilt.shards_resumed, rebuilt.shards_run) == (0, 3)


def test_an_object_store_build_of_another_commit_is_up_to_date(tmp_path, monkeypatch):
    with s3_server("dyana-resume") as _:
        monkeypatch.setenv("DYANA_STAGING", str(tmp_path / "staging"))
        url = "s3://dyana-resume/data"
        _no_read_back(monkeypatch)  # the statistics come from the workers here too
        first = _build(url)
        assert not first.up_to_date
        for module in (engine, object_store):
            monkeypatch.setattr(module, "git_commit", lambda: OTHER)
        calls = _counting(monkeypatch)
        again = _build(url)
        assert again.up_to_date and calls == [4] and again.manifest == first.manifest


def _no_run_read_back(monkeypatch) -> None:
    from pipeline.jobs import evaluate as evaluate_module

    def refused(run_dir):
        raise AssertionError("pipeline eval read the run back for its summary")

    monkeypatch.setattr(evaluate_module, "summarize", refused)


def _summary(run: Path, **options) -> list[str]:
    """evaluate()'s printed summary of ``run``, without its timing and path lines."""
    import io

    from pipeline.jobs.evaluate import evaluate

    stream = io.StringIO()
    evaluate(stream=stream, out=run, slice_name="test-1k", resolution=16, workers=0, progress=False, **options)
    return [line for line in stream.getvalue().splitlines() if not line.startswith(("  time:", "  -> "))]


def test_eval_counts_come_from_the_shards_and_the_state(tmp_path, monkeypatch):
    """`pipeline eval`'s counts are summed from what its tasks returned (and the resume state
    kept for a resumed shard), equal to scoring's reading of the whole run."""
    from pipeline.jobs import evaluate as evaluate_module
    from pipeline.jobs.evaluate import summarize

    mixed = {"policy_ref": "tests.pipeline.faulty_policies:Mixed", "episodes": 5, "shard_size": 2, "isolate": False}
    real = evaluate_module.eval_shard

    def dies(task, *args):
        if task.first == 2:
            raise KeyboardInterrupt
        return real(task, *args)

    with monkeypatch.context() as patch:
        patch.setattr(evaluate_module, "eval_shard", dies)
        with pytest.raises(KeyboardInterrupt):
            _summary(tmp_path / "mixed", **mixed)
    with monkeypatch.context() as patch:
        _no_run_read_back(patch)
        resumed = _summary(tmp_path / "mixed", **mixed)
    assert resumed == summarize(tmp_path / "mixed").lines(tracebacks=True)
    assert "4 error(s)" in resumed[0] and "error in episode 1:" in resumed[2]
    with monkeypatch.context() as patch:
        _no_run_read_back(patch)
        oracle = _summary(tmp_path / "oracle", policy_ref="oracle", episodes=3, shard_size=2)
    assert oracle == summarize(tmp_path / "oracle").lines() and "localized 3/3" in oracle[1]


def test_a_shard_whose_statistics_a_worker_cannot_compute_is_read_by_the_driver(reference, tmp_path, monkeypatch):
    """A worker that cannot compute its shard's statistics (a non-finite value) returns none;
    the driver reads that shard where the output is (and would name the file), as before."""
    import catalog.tables.stats

    def fails(shard):
        raise ShardError("a non-finite value")

    monkeypatch.setattr(catalog.tables.stats, "shard_partial", fails)  # the worker's; the runner keeps its own
    result = _build(tmp_path)
    monkeypatch.undo()
    assert result.manifest.hash == reference.hash  # it covers stats.json's sha256
    _stats_are_the_folders(tmp_path / SLICE)
