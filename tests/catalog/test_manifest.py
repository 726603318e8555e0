import json
import re
import subprocess
from dataclasses import replace

import pytest

from catalog.store.hashing import canonical_json, sha256_bytes, sha256_file, slice_hash
from catalog.store.manifest import (
    SEAL_KEY,
    CodeInfo,
    Manifest,
    compute_hash,
    git_commit,
    load_manifest,
    seal_of,
    write_manifest,
)
from catalog.store.records import FileRecord, ShardRecord, shard_paths
from schemas.errors import ShardError

from .conftest import CODE, SETTINGS


def _shard(first, end, frames, tag):
    paths = shard_paths(first, end)
    files = {k: FileRecord(paths[k], sha256_bytes(f"{tag}-{k}".encode()), 10 + i) for i, k in enumerate(paths)}
    return ShardRecord((first, end), frames, files)


SHARDS = (_shard(0, 2, 40, "a"), _shard(2, 3, 21, "b"))


def test_sha256_file_streams(tmp_path):
    data = bytes(range(256)) * 10000
    (tmp_path / "f").write_bytes(data)
    assert sha256_file(tmp_path / "f") == sha256_bytes(data)


def test_slice_hash_definition():
    hashes = [h for s in SHARDS for h in s.file_hashes()]
    stats = FileRecord("stats.json", sha256_bytes(b"stats"), 5)
    payload = (
        '{"files":[' + ",".join(f'"{h}"' for h in hashes) + '],"seed":7,"settings":' + canonical_json(SETTINGS)
        + f',"slice":"linear-fast","stats":"{stats.sha256}"' + "}"
    )
    expected = sha256_bytes(payload.encode())
    assert compute_hash(SETTINGS, SHARDS, "linear-fast", 7, stats) == expected
    assert slice_hash(SETTINGS, hashes, slice_name="linear-fast", seed=7, stats=stats.sha256) == expected
    assert [h for h in SHARDS[0].file_hashes()] == [SHARDS[0].files[k].sha256 for k in ("frames", "episodes", "mcap")]


def test_hash_changes_with_any_file_hash_or_setting():
    base = compute_hash(SETTINGS, SHARDS)
    assert compute_hash(dict(SETTINGS), list(SHARDS)) == base
    seen = {base}
    for i, shard in enumerate(SHARDS):
        for kind, record in shard.files.items():
            files = dict(shard.files)
            files[kind] = replace(record, sha256=sha256_bytes(b"other"))
            shards = list(SHARDS)
            shards[i] = replace(shard, files=files)
            seen.add(compute_hash(SETTINGS, shards))
    for key, value in [("fps", 10), ("resolution", 64), ("jpeg_quality", 91), ("extra", True)]:
        seen.add(compute_hash({**SETTINGS, key: value}, SHARDS))
    seen.add(compute_hash(SETTINGS, SHARDS[::-1]))
    seen.add(compute_hash(SETTINGS, SHARDS, "linear-slow"))
    seen.add(compute_hash(SETTINGS, SHARDS, None, 2))
    seen.add(compute_hash(SETTINGS, SHARDS, None, None, FileRecord("stats.json", sha256_bytes(b"x"), 1)))
    assert len(seen) == 1 + 6 + 4 + 1 + 3


def test_manifest_round_trip_is_canonical(tmp_path):
    manifest = Manifest.create("linear-fast", 7, SETTINGS, SHARDS[::-1], code=CODE, extra={"policy": "scripted"})
    assert [s.first for s in manifest.shards] == [0, 2]
    assert (manifest.episodes, manifest.frames) == (3, 61)
    path = write_manifest(tmp_path, manifest)
    text = path.read_text()
    assert text.endswith("}\n") and text == manifest.to_json()
    data = json.loads(text)
    assert list(data) == sorted(data)
    assert data["policy"] == "scripted" and data["code"] == {"version": "0.1.0", "commit": CODE.commit}
    assert data["shards"][0]["files"]["mcap"]["path"] == "mcap/000000-000001.mcap"
    loaded = load_manifest(tmp_path)
    assert loaded == manifest
    assert loaded.to_json() == text
    assert [p.name for p in tmp_path.iterdir()] == ["catalog.json"]


def test_manifest_accepts_code_as_dict():
    manifest = Manifest.create("x", 1, SETTINGS, SHARDS, code=CODE)
    again = Manifest(
        slice="x", seed=1, episodes=3, frames=61, code={"version": "0.1.0", "commit": CODE.commit},
        settings=SETTINGS, shards=list(SHARDS), hash=manifest.hash,
    )
    assert again == manifest


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d.pop("hash"), "missing key"),
        (lambda d: d.update(frames=60), "frames is 60"),
        (lambda d: d["settings"].update(fps=30), "does not match"),
        (lambda d: d["shards"][0]["files"]["frames"].update(sha256="0" * 64), "does not match"),
        (lambda d: d["shards"][0]["files"]["frames"].update(path="../x.parquet"), "path"),
        (lambda d: d["shards"][1].update(episodes=[1, 2]), "must be 'frames/000001-000001.parquet'"),
        (lambda d: d["shards"].reverse(), "ordered and disjoint"),
        (lambda d: d["code"].update(commit="abc-dirty"), "commit"),
    ],
)
def test_load_refuses_bad_manifest_naming_it(tmp_path, mutate, message):
    data = Manifest.create("linear-fast", 7, SETTINGS, SHARDS, code=CODE).to_dict()
    mutate(data)
    data[SEAL_KEY] = seal_of(data)  # re-sealed: what the checks beyond the seal refuse
    (tmp_path / "catalog.json").write_text(json.dumps(data))
    with pytest.raises(ShardError, match=message) as info:
        load_manifest(tmp_path)
    assert str(tmp_path / "catalog.json") in str(info.value)


@pytest.mark.parametrize(
    "mutate, keys",
    [
        (lambda d: d.update(policy="oracle"), "changed: policy"),
        (lambda d: d.update(privileged=False), "changed: privileged"),
        (lambda d: d.update(deadline_s=5.0), "changed: deadline_s"),
        (lambda d: d["code"].update(commit="f" * 40), "changed: code"),
        (lambda d: d["vlm"].update(temperature=0.7), "changed: vlm"),
        (lambda d: d["vlm"].update(model="other"), "changed: vlm"),
        (lambda d: d["shards"][0]["files"]["frames"].update(size=11), "changed: shards"),
        (lambda d: d.update(note="hello"), "added: note"),
        (lambda d: d.pop("deadline_s"), "removed: deadline_s"),
        (lambda d: d.update(hash="0" * 64), "changed: hash"),
    ],
)
def test_an_edit_of_any_key_is_refused_naming_it(tmp_path, mutate, keys):
    extra = {"policy": "predictive", "privileged": True, "deadline_s": None, "vlm": {"model": "m", "temperature": 0.0}}
    data = Manifest.create("linear-fast", 7, SETTINGS, SHARDS, code=CODE, extra=extra).to_dict()
    mutate(data)
    (tmp_path / "catalog.json").write_text(json.dumps(data))
    with pytest.raises(ShardError, match=re.escape(keys)) as info:
        load_manifest(tmp_path)
    assert str(info.value).startswith(f"{tmp_path / 'catalog.json'}: edited after it was written")


def test_the_seal_covers_every_other_key_and_leaves_the_hash_alone(tmp_path):
    manifest = Manifest.create("linear-fast", 7, SETTINGS, SHARDS, code=CODE, extra={"policy": "p"})
    data = manifest.to_dict()
    assert set(data[SEAL_KEY]) == set(data) - {SEAL_KEY}
    assert data[SEAL_KEY]["policy"] == sha256_bytes(canonical_json("p").encode())
    assert data["hash"] == compute_hash(SETTINGS, manifest.shards, "linear-fast", 7)
    assert Manifest.from_dict(data) == manifest  # the seal is no extra key


def test_a_manifest_without_a_seal_is_refused_with_the_migrate_command(tmp_path):
    data = Manifest.create("linear-fast", 7, SETTINGS, SHARDS, code=CODE).to_dict()
    del data[SEAL_KEY]
    (tmp_path / "catalog.json").write_text(json.dumps(data))
    with pytest.raises(ShardError, match=f"no {SEAL_KEY}.*run `catalog migrate {re.escape(str(tmp_path))}`"):
        load_manifest(tmp_path)
    assert load_manifest(tmp_path, sealed=False).hash == data["hash"]


def test_load_missing_or_invalid_json(tmp_path):
    with pytest.raises(ShardError, match="no catalog.json"):
        load_manifest(tmp_path)
    (tmp_path / "catalog.json").write_text('{"slice": ')
    with pytest.raises(ShardError, match="not valid JSON"):
        load_manifest(tmp_path)


def test_shard_record_checks_names():
    with pytest.raises(ShardError, match="must be 'mcap/000000-000001.mcap'"):
        files = dict(SHARDS[0].files)
        files["mcap"] = replace(files["mcap"], path="mcap/other.mcap")
        ShardRecord((0, 2), 40, files)
    assert ShardRecord.from_dict(SHARDS[0].to_dict()) == SHARDS[0]


def test_git_commit(tmp_path):
    assert git_commit(tmp_path) is None
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    (tmp_path / "f").write_text("x")
    env = {"GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@e", "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@e"}
    subprocess.run(["git", "-C", str(tmp_path), "add", "f"], check=True)
    commit = ["git", "-C", str(tmp_path), "commit", "-q", "-m", "m"]
    subprocess.run(commit, check=True, env={**env, "PATH": "/usr/bin:/bin"})
    sha = git_commit(tmp_path)
    assert sha and re.fullmatch(r"[0-9a-f]{40}", sha)
    (tmp_path / "f").write_text("dirty")
    assert git_commit(tmp_path) == sha
    own = git_commit()
    assert own is None or re.fullmatch(r"[0-9a-f]{40}", own)
    assert CodeInfo.current().commit == own


@pytest.mark.parametrize("kind", ["fifo", "dev-zero", "folder"])
def test_a_catalog_json_that_is_not_a_regular_file_is_refused_without_reading(slice_dir, kind):
    """Before: a FIFO in catalog.json's place blocked every reader (catalog info/verify,
    scoring eval, pipeline replay) for ever, and a link to /dev/zero read without end."""
    import os
    import threading

    path = slice_dir / "catalog.json"
    path.unlink()
    {"fifo": lambda: os.mkfifo(path), "dev-zero": lambda: path.symlink_to("/dev/zero"), "folder": path.mkdir}[kind]()
    outcome: list[BaseException] = []

    def read() -> None:
        try:
            load_manifest(slice_dir)
        except BaseException as exc:  # reported below
            outcome.append(exc)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(10)
    assert not reader.is_alive(), "load_manifest blocked"
    assert len(outcome) == 1 and isinstance(outcome[0], ShardError), outcome
    assert "catalog.json: not a regular file" in str(outcome[0])


def test_a_catalog_json_holding_a_number_python_cannot_convert_is_named(slice_dir):
    """Before: ValueError ('Exceeds the limit (4300 digits) for integer string conversion')
    escaped load_manifest, a traceback from every reader."""
    path = slice_dir / "catalog.json"
    path.write_text(path.read_text().replace('"seed": ', '"seed": ' + "9" * 5000 + ', "s": ', 1))
    with pytest.raises(ShardError, match="catalog.json: holds a number Dyana cannot read"):
        load_manifest(slice_dir)


def test_a_catalog_json_nested_too_deeply_is_named(slice_dir):
    """Before: RecursionError ('maximum recursion depth exceeded while decoding a JSON array')."""
    path = slice_dir / "catalog.json"
    text = path.read_text().rstrip()
    path.write_text(text[:-1] + ', "x": ' + "[" * 200_000 + "]" * 200_000 + "}")
    with pytest.raises(ShardError, match="catalog.json: JSON nested too deeply"):
        load_manifest(slice_dir)


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity"])
def test_a_catalog_json_holding_nan_is_named_by_every_reader(slice_dir, constant):
    """Before: a NaN in settings (re-sealed: Python's json writes and reads it) was a
    ValueError traceback in catalog verify, scoring eval, ds[i] and .stats."""
    path = slice_dir / "catalog.json"
    data = json.loads(path.read_text())
    data["settings"]["resolution"] = float(constant.replace("Infinity", "inf"))
    path.write_text(json.dumps(data))
    with pytest.raises(ShardError, match=f"catalog.json: holds {constant}, which JSON does not allow"):
        load_manifest(slice_dir)
