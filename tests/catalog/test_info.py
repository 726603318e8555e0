"""`catalog info DIR|URL` through the real CLI: a folder's versions, contents and size, whether
this code rebuilds it byte for byte, and one clear line for what is no Dyana folder."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from catalog.store.info import rebuild_verdict
from catalog.store.manifest import Manifest, write_manifest
from catalog.store.versions import installed_versions
from catalog.tables.shard import ShardWriter
from pipeline.cli_catalog import main
from schemas.versions import DATASET_VERSION, HAND_MODEL, POSE_HAND_COMMIT

from .conftest import CODE, SETTINGS, make_frames, make_images, make_spec, write_slice


def info(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["info", *args])
    out, err = capsys.readouterr()
    return code, out, err


def disk_bytes(root: Path) -> tuple[int, int]:
    """Files and bytes under ``root``, counted on disk."""
    sizes = [os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(root) for f in files]
    return len(sizes), sum(sizes)


def rollout_folder(root: Path, settings: dict) -> Manifest:
    """Two rollouts of policy ``p`` (one cut short by an error) and their catalog.json, recorded
    with this code's hand unless ``settings`` says otherwise."""
    settings = {key: value for key, value in {"hand_model": HAND_MODEL, **settings}.items() if value is not None}
    with ShardWriter(root, 0, 2, settings, rollout=True) as writer:
        for i, (status, keep) in enumerate((("ok", None), ("error", 7))):
            spec = make_spec(i, slice_name="test-1k")
            rng = np.random.default_rng([5, i])
            frames = make_frames(spec, rng, num_frames=keep)
            writer.add_episode(spec, frames, make_images(frames.num_frames, rng), policy="p", status=status,
                               error="policy raised" if status == "error" else None)
    manifest = Manifest.create("test-1k", 1000, settings, [writer.record], code=CODE, extra={"policy": "p"})
    write_manifest(root, manifest)
    return manifest


def test_a_built_slice_as_text(slice_dir, capsys):
    code, out, err = info(capsys, str(slice_dir))
    assert code == 0 and err == ""
    rows = dict(line.split(None, 1) for line in out.splitlines())
    assert list(rows) == ["folder", "kind", "dataset", "code", "slice", "settings", "episodes", "frames", "size",
                          "hash", "versions", "rebuild"]
    manifest = Manifest.from_dict(json.loads((slice_dir / "catalog.json").read_text()))
    assert rows["folder"] == str(slice_dir)
    assert rows["kind"] == "built slice (ground truth)"
    assert rows["dataset"] == f"{DATASET_VERSION} (this code writes {DATASET_VERSION})"
    assert rows["code"] == f"0.1.0, commit {CODE.commit}"
    assert rows["slice"] == "linear-fast, seed 7"
    assert rows["settings"] == ("formats=parquet,mcap fps=20 hand_model=null image_format=jpeg jpeg_quality=90 "
                                "obstacle_clearance=false "
                                "protocol=null resolution=32")
    assert rows["episodes"] == "5 in 3 shards"
    assert rows["frames"] == f"{manifest.frames:,}"
    assert rows["size"].endswith(f"in {disk_bytes(slice_dir)[0]} files")
    assert rows["hash"] == manifest.hash[:16]
    assert rows["versions"] == "not recorded (written before Dyana recorded them)"
    assert rows["rebuild"] == (f"yes: this code writes dataset {DATASET_VERSION} (--renderer window), as the folder records "
                               "(it records no library versions: written before Dyana recorded them)")


def test_json_matches_the_manifest_and_the_disk(slice_dir, capsys):
    code, out, _ = info(capsys, str(slice_dir), "--json")
    assert code == 0
    data = json.loads(out)
    manifest = Manifest.from_dict(json.loads((slice_dir / "catalog.json").read_text()))
    files, size = disk_bytes(slice_dir)
    assert data == {
        "path": str(slice_dir), "kind": "slice", "policy": None, "slice": "linear-fast", "seed": 7,
        "dataset_version": DATASET_VERSION, "code": CODE.to_dict(), "settings": SETTINGS,
        "episodes": 5, "frames": manifest.frames, "shards": 3, "files": files, "bytes": size,
        "hash": manifest.hash,
        "rebuild": {"possible": True, "reason": f"this code writes dataset {DATASET_VERSION} (--renderer window), as the folder records "
                                                "(it records no library versions: written before Dyana recorded them)"},
        "versions": None,
    }
    code, again, _ = info(capsys, str(slice_dir / "catalog.json"), "--json")  # the manifest's own path works too
    assert code == 0 and json.loads(again) == {**data, "path": str(slice_dir / "catalog.json")}


def test_rollouts_name_their_policy(tmp_path, capsys):
    rollout_folder(tmp_path / "run", SETTINGS)
    code, out, _ = info(capsys, str(tmp_path / "run"), "--json")
    assert code == 0
    data = json.loads(out)
    assert (data["kind"], data["policy"], data["slice"], data["seed"], data["episodes"]) == (
        "rollouts", "p", "test-1k", 1000, 2)
    assert data["rebuild"]["possible"] is True
    _, text, _ = info(capsys, str(tmp_path / "run"))
    assert "kind      rollouts of policy p\n" in text


def test_an_older_dataset_version_is_readable_but_not_rebuilt(tmp_path, capsys):
    write_slice(tmp_path / "old", settings={**SETTINGS, "dataset_version": "2.0.0"})
    code, out, _ = info(capsys, str(tmp_path / "old"))
    assert code == 0
    assert f"dataset   2.0.0 (this code writes {DATASET_VERSION})\n" in out
    assert out.splitlines()[-1] == (
        "rebuild   no: written by dataset 2.0.0; this code writes 5.0.0: readable, not re-executable; "
        f"check out commit {CODE.commit} to rebuild it"
    )


def test_a_run_from_before_the_hand_body_is_read_not_rebuilt(tmp_path, capsys):
    rollout_folder(tmp_path / "run", {**SETTINGS, "hand_model": None})
    code, out, _ = info(capsys, str(tmp_path / "run"), "--json")
    verdict = json.loads(out)["rebuild"]
    assert code == 0 and verdict["possible"] is False
    assert verdict["reason"].startswith("a run recorded before the hand was a body (no settings.hand_model);")
    assert f"commit {POSE_HAND_COMMIT} re-executes it" in verdict["reason"]


def test_a_real_time_run_is_not_rebuilt(tmp_path, capsys):
    rollout_folder(tmp_path / "run", {**SETTINGS, "protocol": {"realtime": True, "latency_frames": 0}})
    code, out, _ = info(capsys, str(tmp_path / "run"), "--json")
    assert code == 0
    assert json.loads(out)["rebuild"] == {
        "possible": False, "reason": "a real-time run (settings.protocol.realtime) depends on the machine's timing"
    }
    _, text, _ = info(capsys, str(tmp_path / "run"))
    assert 'protocol={"latency_frames":0,"realtime":true}' in text


def _repeats(root: Path) -> None:
    rollout_folder(root / "repeat-00", SETTINGS)
    (root / "repeats.json").write_text(json.dumps({"runs": [{"path": "repeat-00", "hash": "x"}]}))


def _edited(root: Path) -> None:
    write_slice(root)
    data = json.loads((root / "catalog.json").read_text())
    data["seed"] = 8
    (root / "catalog.json").write_text(json.dumps(data))


@pytest.mark.parametrize(
    "make, target, needle",
    [
        (None, "missing", "missing: no such folder"),
        (lambda root: root.mkdir(), "empty", "no catalog.json (not a built slice or run folder"),
        (_repeats, "repeats", "is a folder of 1 repeat (repeat-00, indexed by repeats.json), not one run: pass one"),
        (lambda root: write_slice(root / "linear-fast"), "out",
         "no catalog.json here; it holds Dyana folders (linear-fast): give one of them, e.g. "),
        (_edited, "edited", "catalog.json: edited after it was written (changed: seed;"),
    ],
    ids=["missing", "not-dyana", "repeats", "build-output", "edited"],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, make, target, needle):
    root = tmp_path / target
    if make is not None:
        make(root)
    code, out, err = info(capsys, str(root))
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and err.startswith("catalog info: error: ")
    assert needle in err


def test_the_console_script_gives_no_traceback(tmp_path):
    done = subprocess.run([sys.executable, "-m", "pipeline.cli_catalog", "info", str(tmp_path / "nowhere")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == f"catalog info: error: {tmp_path / 'nowhere'}: no such folder\n"


def test_a_folder_in_object_storage(slice_dir, capsys):
    """``catalog info s3://...`` reads the manifest there and says what it says locally."""
    from tests.s3_server import s3_server

    with s3_server("dyana-info"):
        import fsspec

        fsspec.filesystem("s3").put(str(slice_dir), "dyana-info/linear-fast", recursive=True)
        code, out, err = info(capsys, "s3://dyana-info/linear-fast", "--json")
        missing, _, gone = info(capsys, "s3://dyana-info/nothing")
    assert code == 0, err
    _, local, _ = info(capsys, str(slice_dir), "--json")
    assert json.loads(out) == {**json.loads(local), "path": "s3://dyana-info/linear-fast"}
    assert missing == 2 and "no catalog.json (not a built slice or run folder" in gone


def _with_versions(root: Path, versions: dict) -> Manifest:
    """A built slice whose catalog.json records ``versions`` (re-sealed, as a build writes it)."""
    write_slice(root)
    manifest = Manifest.from_dict(json.loads((root / "catalog.json").read_text()))
    updated = Manifest.create(manifest.slice, manifest.seed, manifest.settings, manifest.shards, code=manifest.code,
                              stats=manifest.stats, versions=versions)
    write_manifest(root, updated)
    return updated


def test_the_recorded_versions_are_printed_and_compared_with_the_installed_ones(tmp_path, capsys, monkeypatch):
    installed = installed_versions()
    _with_versions(tmp_path / "same", installed)
    code, out, _ = info(capsys, str(tmp_path / "same"))
    rows = dict(line.split(None, 1) for line in out.splitlines())
    assert code == 0
    assert rows["versions"] == " ".join(f"{k}={v or '(none)'}" for k, v in sorted(installed.items()))
    assert f"numpy={np.__version__}" in rows["versions"]
    assert rows["rebuild"] == f"yes: this code writes dataset {DATASET_VERSION} (--renderer window), as the folder records, with the " \
                              "library versions it records"

    monkeypatch.setattr("catalog.store.info.installed_versions", lambda: {**installed, "pyarrow": "99.0.0"})
    code, out, _ = info(capsys, str(tmp_path / "same"), "--json")
    verdict = json.loads(out)["rebuild"]
    assert code == 0 and verdict["possible"] is False
    assert f"(recorded pyarrow {installed['pyarrow']}, installed 99.0.0)" in verdict["reason"]
    assert "numpy" not in verdict["reason"]
    assert json.loads(out)["versions"] == installed


def test_rebuild_verdict_names_every_differing_version(tmp_path):
    manifest = _with_versions(tmp_path / "s", {"python": "3.11.7", "numpy": "2.1.0", "opencv-python-headless": None})
    same = rebuild_verdict(manifest, {"python": "3.11.7", "numpy": "2.1.0", "pyarrow": "1"})
    assert same.possible
    other = rebuild_verdict(manifest, {"python": "3.12.1", "numpy": "2.2.0", "opencv-python-headless": "4.10.0.84"})
    assert not other.possible
    assert "(recorded numpy 2.1.0, installed 2.2.0; recorded opencv-python-headless (none), installed 4.10.0.84)" \
        in other.reason
    assert other.reason.endswith("to rebuild it byte for byte, pip install 'numpy==2.1.0'")  # what to run, not the lock
    # another Python alone: the libraries decide the bytes (a 3.12 build read under 3.11 verifies byte for byte),
    # so no advice to install a lock that is already installed; verify is named to confirm
    python = rebuild_verdict(manifest, {"python": "3.12.1", "numpy": "2.1.0"})
    assert python.possible and "recorded python 3.11.7, installed 3.12.1" in python.reason
    assert "constraints" not in python.reason and "catalog verify DIR --sample 1" in python.reason
