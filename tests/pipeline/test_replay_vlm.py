"""`pipeline replay` of a VLM run compares every field of the audit trail it can
re-derive (request settings, prompt, outcome, answer, ...) and the trail's files are
sealed in the manifest, so an edited answer, outcome or setting, an extra record or an
extra trail file is named, even with the manifest re-hashed and re-sealed (issue 26)."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from catalog.store.hashing import sha256_file
from catalog.store.manifest import load_manifest
from catalog.store.records import FileRecord
from catalog.tables.integrity import verify_files
from pipeline.jobs.evaluate import evaluate
from pipeline.jobs.migrate import migrate
from pipeline.jobs.replay import replay
from schemas.errors import ReplayMismatch, ShardError

from .tamper import copy_of, reseal, unseal

RESOLUTION = 48


@pytest.fixture(scope="module")
def vlm_run(tmp_path_factory):
    server = subprocess.Popen([sys.executable, "-m", "pipeline.remote.loopback_vlm", "--mode", "ok"],
                              stdout=subprocess.PIPE, text=True)
    try:
        url = server.stdout.readline().strip()
        out = tmp_path_factory.mktemp("vlm") / "run"
        evaluate(f"vlm:{url}", "test-1k", out, episodes=2, workers=0, resolution=RESOLUTION, shard_size=2,
                 progress=False, summary=False, stream=io.StringIO(),
                 config={"model": "loopback-perception", "timeout_s": 10.0})
    finally:
        server.terminate()
        server.wait(timeout=10)
    return out


@pytest.fixture
def run(vlm_run, tmp_path):
    return copy_of(vlm_run, tmp_path)


def rewrite_trail(folder: Path, mutate) -> None:
    """Rewrite the run's trail file through ``mutate`` (a list of records), then list its
    new sha256 in the manifest and re-seal it with Dyana's writer."""
    record = load_manifest(folder).audit[0]
    path = folder / record.path
    records = mutate([json.loads(line) for line in path.read_text().splitlines()])
    path.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in records))
    reseal(folder, audit=[FileRecord(record.path, sha256_file(path), path.stat().st_size)])


def test_the_trail_is_listed_in_the_sealed_manifest_and_the_run_replays(vlm_run):
    manifest = load_manifest(vlm_run)
    assert [r.path for r in manifest.audit] == ["vlm/audit-000000-000002.jsonl"]
    assert sorted(p.name for p in (vlm_run / "vlm").iterdir()) == ["audit-000000-000002.jsonl"]
    assert replay(vlm_run).episodes == 2
    verify_files(vlm_run)


def _set(field, value):
    def mutate(records):
        records[0][field] = value(records[0][field])
        return records
    return mutate


@pytest.mark.parametrize("mutate, field", [
    (_set("answer", lambda a: {**a, "closure": 0.5}), "answer"),
    (_set("outcome", lambda _: "refusal"), "outcome"),
    (_set("detail", lambda _: "made up"), "detail"),
    (_set("request", lambda r: {**r, "temperature": 0.7}), "request"),
    (_set("prompt", lambda p: p + " "), "request 1 differs from the recorded one"),
    (lambda records: records + [{**records[-1], "query": records[-1]["query"] + 1}], "the trail holds"),
])
def test_an_edited_trail_re_sealed_is_named_by_replay(run, mutate, field):
    rewrite_trail(run, mutate)
    with pytest.raises(ReplayMismatch, match=f"audit trail vlm/audit-000000-000002.jsonl: .*{field}") as info:
        replay(run)
    assert info.value.file == "vlm/audit-000000-000002.jsonl"


def test_an_edited_reply_changes_what_replay_derives(run):
    def mutate(records):
        records[0]["reply"]["content"] = json.dumps({"palm_target": [0.0, 0.0, 0.5], "closure": 1.0})
        return records

    rewrite_trail(run, mutate)
    with pytest.raises(ReplayMismatch, match="field answer"):
        replay(run)


def test_a_trail_file_edited_by_hand_is_refused(run):
    path = run / "vlm" / "audit-000000-000002.jsonl"
    path.write_text(path.read_text().replace('"outcome": "ok"', '"outcome": "no"', 1))  # same size
    with pytest.raises(ShardError, match=f"{path}: content changed"):
        replay(run)
    with pytest.raises(ShardError, match=f"{path}: content changed"):
        verify_files(run)


def test_an_extra_trail_file_is_named_listed_or_not(run):
    extra = run / "vlm" / "audit-000002-000004.jsonl"
    shutil.copy(run / "vlm" / "audit-000000-000002.jsonl", extra)
    for check in (replay, verify_files):
        with pytest.raises(ShardError, match=f"{extra}: not listed in catalog.json"):
            check(run)
    listed = [*load_manifest(run).audit, FileRecord("vlm/audit-000002-000004.jsonl", sha256_file(extra), extra.stat().st_size)]
    reseal(run, audit=listed)
    with pytest.raises(ShardError, match="one per shard expected .*vlm/audit-000002-000004.jsonl"):
        replay(run)


def test_vlm_settings_of_the_manifest_are_sealed_and_re_derived(run):
    path = run / "catalog.json"
    original = path.read_text()
    data = json.loads(original)
    data["vlm"]["temperature"] = 0.7
    path.write_text(json.dumps(data, sort_keys=True, indent=2) + "\n")
    with pytest.raises(ShardError, match=r"catalog.json: edited after it was written \(changed: vlm;"):
        replay(run)
    config = dict(data["vlm"])
    path.write_text(original)
    reseal(run, vlm=config)
    with pytest.raises(ReplayMismatch, match='field request.temperature: recorded 0.0, replay gives 0.7'):
        replay(run)
    reseal(run, vlm={**config, "temperature": 0.0, "model": "other"}, policy="vlm:other")
    with pytest.raises(ReplayMismatch, match='field request.model: recorded "loopback-perception", replay gives "other"'):
        replay(run)


def test_a_vlm_run_of_the_previous_release_is_migrated_with_its_trail_index(run):
    manifest = load_manifest(run)
    files = {Path(r.path).name: {"sha256": r.sha256, "size": r.size} for r in manifest.audit}
    (run / "vlm" / "index.json").write_text(json.dumps({"files": files}, indent=2, sort_keys=True) + "\n")
    reseal(run, audit=None)
    unseal(run)  # as the previous release wrote it: the trail's listing in vlm/index.json, no seal
    with pytest.raises(ShardError, match="run `catalog migrate"):
        replay(run)
    report = migrate(run)[0]
    assert report.sealed and not report.already
    assert load_manifest(run).audit == manifest.audit and not (run / "vlm" / "index.json").exists()
    assert replay(run).episodes == 2


def test_migrate_refuses_a_previous_release_vlm_run_whose_trail_changed(run):
    manifest = load_manifest(run)
    files = {Path(r.path).name: {"sha256": "0" * 64, "size": r.size} for r in manifest.audit}
    (run / "vlm" / "index.json").write_text(json.dumps({"files": files}, indent=2, sort_keys=True) + "\n")
    reseal(run, audit=None)
    unseal(run)
    before = (run / "catalog.json").read_text()
    with pytest.raises(ShardError, match="audit-000000-000002.jsonl: changed since the run"):
        migrate(run)
    assert (run / "catalog.json").read_text() == before
