"""The job functions (``build``, ``evaluate``) and the readers' folder argument refuse a
wrong type or value with a SpecError naming the argument, the value cut short, before a
folder is made or anything is read: never a TypeError or AttributeError from deep inside."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from catalog.store.manifest import load_manifest
from catalog.tables.reader import open_folder
from pipeline.jobs.build import build
from pipeline.jobs.evaluate import evaluate
from pipeline.policies.vlm import VLMConfig, template_path
from schemas.errors import SpecError
from scoring.io import load_run

SMALL = {"episodes": 1, "workers": 0, "resolution": 16, "shard_size": 1, "progress": False}
LONG = "x" * 10_000
BIN = Path(sys.executable).parent


def _made(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


@pytest.mark.parametrize(("option", "value", "named"), [
    ("formats", None, "--formats"),
    ("formats", 5, "--formats"),
    ("formats", 1.5, "--formats"),
    ("formats", [5], "--formats"),
    ("scheduler", "nope", "--scheduler"),
    ("scheduler", "", "--scheduler"),
    ("scheduler", 1.5, "--scheduler"),
    ("scheduler", "tcp://127.0.0.1:99999", "--scheduler"),
    ("overwrite", "no", "overwrite"),
    ("overwrite", None, "overwrite"),
    ("progress", 1, "progress"),
    ("episodes", LONG, "--episodes"),
    ("workers", LONG, "--workers"),
    ("shard_size", LONG, "--shard-size"),
    ("resolution", LONG, "resolution"),
])
def test_build_refuses_a_bad_option_before_making_the_folder(tmp_path, option, value, named):
    """Before: formats=None was a TypeError, a malformed scheduler left OUT/<slice>/.lock
    behind, overwrite="no" replaced another build, and a 10 kB value was echoed whole."""
    with pytest.raises(SpecError, match=named) as caught:
        build("linear-fast", tmp_path / "out", **{**SMALL, option: value})
    assert len(str(caught.value)) < 300 and "\n" not in str(caught.value)
    assert _made(tmp_path) == []


@pytest.mark.parametrize("out", [None, 5, 1.5, [], b"out", "out\x00x"])
def test_build_and_evaluate_name_an_out_that_is_not_a_folder_name(tmp_path, monkeypatch, out):
    """Before: TypeError from pathlib (expected str, bytes or os.PathLike) or ValueError (embedded null byte)."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SpecError, match="out must be a folder or file name"):
        build("linear-fast", out, **SMALL)
    with pytest.raises(SpecError, match="out must be a folder or file name"):
        evaluate("still", "linear-fast", out, **SMALL, summary=False)
    assert _made(tmp_path) == []


@pytest.mark.parametrize("protocol", ["latency", 3, [1], {"latency_frames": 2}, math.nan])
def test_evaluate_names_a_protocol_that_is_not_an_eval_protocol(tmp_path, protocol):
    """Before: AttributeError ('str' object has no attribute 'plain'); 0, [] and {} ran a plain run."""
    with pytest.raises(SpecError, match="protocol must be a pipeline.loop.conditions.EvalProtocol"):
        evaluate("still", "linear-fast", tmp_path / "run", protocol=protocol, **SMALL, summary=False)
    assert _made(tmp_path) == []


@pytest.mark.parametrize(("config", "message"), [
    (None, "needs --model NAME"),
    ({}, "needs --model NAME"),
    ({"model": 5}, "needs --model NAME.*got 5"),
    ({"model": "m", "colour": 1}, "unknown setting 'colour'"),
    (["model", "m"], "must be a dict of --vlm-\\* settings"),
    ({"model": "m", "template": "../../../etc/x"}, "no such template"),
    ({"model": "m", "template": 7}, "--vlm-template must be a template name or a .txt file, got 7"),
])
def test_a_vlm_configuration_is_checked_field_by_field(tmp_path, config, message):
    """Before: TypeError (VLMConfig.__init__() missing 'model' / unexpected keyword 'colour'),
    AttributeError for a template that is not text; a built-in template name could be a path."""
    with pytest.raises(SpecError, match=message):
        evaluate("vlm:http://127.0.0.1:9/v1", "linear-fast", tmp_path / "run", config=config, **SMALL, summary=False)
    assert _made(tmp_path) == []


def test_a_vlm_template_name_stays_in_the_built_in_folder(tmp_path):
    (tmp_path / "mine.txt").write_text("my prompt")
    assert template_path("v1").name == "v1.txt"
    assert template_path(str(tmp_path / "mine.txt")) == tmp_path / "mine.txt"
    with pytest.raises(SpecError, match="no such template"):
        template_path(f"../../../../../../{tmp_path}/mine")
    with pytest.raises(SpecError, match="unknown setting"):
        VLMConfig.from_dict({"url": "http://x", "model": "m", "extra": 1})


@pytest.mark.parametrize("directory", [None, 5, 1.5, True, [], {}, b"folder", "a\x00b"])
@pytest.mark.parametrize("reader", [open_folder, load_manifest, load_run])
def test_readers_name_a_directory_that_is_not_a_folder_name(reader, directory):
    """Before: TypeError from pathlib (``open_folder(None)``), ValueError for a NUL byte."""
    with pytest.raises(SpecError, match="directory must be a folder or file name"):
        reader(directory)


@pytest.mark.parametrize("linked", ["frames", "episodes/inner", "catalog.json"])
def test_a_symbolic_link_inside_the_output_folder_is_refused_before_anything_is_written(tmp_path, linked):
    """Before: with ``frames -> elsewhere``, a rebuild --overwrite wrote its shards into
    elsewhere and removed the shards it found there (files outside the output folder)."""
    out = tmp_path / "out"
    build("linear-fast", out, **{**SMALL, "episodes": 2})
    folder = out / "linear-fast"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "notes.txt").write_text("not Dyana's")
    target = folder / linked
    if linked == "frames":
        for shard in (folder / "frames").iterdir():
            shard.rename(elsewhere / shard.name)
        (folder / "frames").rmdir()
    elif linked == "catalog.json":
        target.unlink()
        elsewhere = elsewhere / "notes.txt"
    target.symlink_to(elsewhere)
    before = sorted((p.name, p.stat().st_size) for p in tmp_path.rglob("*") if not p.is_symlink() and p.is_file())
    with pytest.raises(SpecError, match=f"{linked}: a symbolic link inside the output folder"):
        build("linear-fast", out, **{**SMALL, "episodes": 2, "shard_size": 2, "overwrite": True})
    assert sorted((p.name, p.stat().st_size) for p in tmp_path.rglob("*") if not p.is_symlink() and p.is_file()) == before


@pytest.mark.parametrize("argv", [
    ["catalog", "info", "s3://"],
    ["catalog", "verify", "s3:///"],
    ["scoring", "eval", "s3://"],
    ["pipeline", "replay", "s3:///x"],
    ["pipeline", "build", "--slice", "linear-fast", "--episodes", "1", "--out", "s3://"],
])
def test_a_url_without_a_bucket_is_one_line_naming_it(tmp_path, argv):
    """Before: s3fs's ValueError ("Attempt to open non key-like path") as a traceback, and a
    build to s3:// reported 'built ... -> s3:/linear-fast/catalog.json'."""
    env = {**os.environ, "AWS_MAX_ATTEMPTS": "1", "AWS_ENDPOINT_URL": "http://127.0.0.1:9",
           "AWS_ACCESS_KEY_ID": "x", "AWS_SECRET_ACCESS_KEY": "y"}
    result = subprocess.run([str(BIN / argv[0]), *argv[1:]], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                            env=env)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "names no bucket" in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_10_kb_policy_reference_is_cut_short_in_its_refusal(tmp_path):
    """Before: 'unknown policy 'xxx...'' repeated all 10,000 characters."""
    with pytest.raises(SpecError, match=r"unknown policy 'x+\.\.\. \(10,002 characters\)") as caught:
        evaluate(LONG, "linear-fast", tmp_path / "run", **SMALL, summary=False)
    assert len(str(caught.value)) < 400 and _made(tmp_path) == []


def test_verify_replay_view_and_repeats_name_a_bad_argument(tmp_path):
    """Before: TypeError ('>=' not supported between 'str' and 'int') for verify(sample='3'),
    numpy's ValueError for sample=-1, AttributeError for rng='3'; TypeError for
    replay(shards=1.5); TypeError or IndexError for write_recording(episode='3' or 1.5) and
    pathlib's TypeError for out=5; AttributeError ('to_dict') for evaluate_repeats(protocol='x')."""
    from pipeline.jobs.repeats import evaluate_repeats
    from pipeline.jobs.replay import replay
    from pipeline.jobs.verify import verify
    from pipeline.jobs.view import write_recording

    build("linear-fast", tmp_path / "out", **{**SMALL, "episodes": 2})
    folder = tmp_path / "out" / "linear-fast"
    for sample in ("3", -1, 0, 1.5, True):
        with pytest.raises(SpecError, match="--sample must be an integer >= 1"):
            verify(folder, sample=sample)
    with pytest.raises(SpecError, match="rng must be a numpy.random.Generator"):
        verify(folder, sample=1, rng="3")
    for shards in (1.5, 3, "0", [0.0]):
        with pytest.raises(SpecError, match="shards must be a list"):
            replay(folder, shards=shards)
    pytest.importorskip("rerun")
    for episode in ("3", 1.5, None, True):
        with pytest.raises(SpecError, match="--episode must be an integer"):
            write_recording(folder, episode, tmp_path / "x.rrd")
    with pytest.raises(SpecError, match="out must be a folder or file name"):
        write_recording(folder, 0, 5)
    with pytest.raises(SpecError, match="protocol must be a pipeline.loop.conditions.EvalProtocol"):
        evaluate_repeats("still", "linear-fast", tmp_path / "rep", 2, "latency", **SMALL)
    assert not (tmp_path / "rep").exists() and not (tmp_path / "x.rrd").exists()


def test_an_empty_out_is_not_the_current_folder(tmp_path, monkeypatch):
    """Before: build(out='') built into ./linear-fast and evaluate(out='') wrote its run into
    the current folder, beside whatever it held."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SpecError, match="out must be a folder or file name"):
        build("linear-fast", "", **SMALL)
    with pytest.raises(SpecError, match="out must be a folder or file name"):
        evaluate("still", "linear-fast", "", **SMALL, summary=False)
    assert _made(tmp_path) == []
