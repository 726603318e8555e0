"""The typed job request (pipeline.jobs.spec): its parts refuse a bad value by name when
made, the CLI's flag groups and the Python options give the same JobSpec, and no function
of the job layer takes more than 8 parameters (the request's parts carry the rest)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from pipeline import cli as pipeline_cli
from pipeline import job_flags
from pipeline.jobs.spec import JobSpec, PolicyChoice, Selection, Storage, byte_settings, job_spec
from pipeline.jobs.tasks import Execution
from pipeline.loop.conditions import EvalProtocol
from schemas.cli import make_parser
from schemas.errors import SpecError

JOBS = Path(__file__).resolve().parents[2] / "pipeline" / "jobs"
MAX_PARAMETERS = 8


def parameters(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = node.args
    return len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)


def test_no_function_of_the_job_layer_takes_more_than_8_parameters():
    wide = [
        f"{path.name}:{node.lineno} {node.name} ({parameters(node)})"
        for path in sorted(JOBS.glob("*.py"))
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and parameters(node) > MAX_PARAMETERS
    ]
    assert len(list(JOBS.glob("*.py"))) > 10 and wide == []


@pytest.mark.parametrize(("make", "named"), [
    (lambda: Selection("linear-fast", shard_size=0), "--shard-size must be an integer >= 1, got 0"),
    (lambda: Selection(5), "slice must be text or None, got 5"),
    (lambda: Storage(None), "out must be a folder or file name"),
    (lambda: Storage("out", overwrite="no"), "overwrite must be True or False, got 'no'"),
    (lambda: Execution.of(1000), r"--workers must be an integer in \[0, 64\]"),
    (lambda: Execution.of(1, progress=1), "progress must be True or False, got 1"),
    (lambda: PolicyChoice("still", deadline_s=-1.0), "--deadline"),
    (lambda: PolicyChoice("still", protocol="x"), "protocol must be a pipeline.loop.conditions.EvalProtocol"),
    (lambda: byte_settings(renderer="fast"), r"renderer must be one of \['window'\], got 'fast'"),
    (lambda: byte_settings(resolution=8), r"resolution must be an integer in \[16, 1024\], got 8"),
    (lambda: JobSpec(Selection("x"), "settings", Execution(0), Storage("out")), "settings must be a BuildSettings"),
])
def test_a_part_names_its_bad_value_when_made(make, named):
    with pytest.raises(SpecError, match=named):
        make()


def test_the_episodes_check_is_one_rule_for_a_slice_and_a_specs_file():
    assert Selection("linear-fast").first_episodes(100, "linear-fast") == 100
    assert Selection("linear-fast", episodes=3).first_episodes(100, "linear-fast") == 3
    assert Selection(None, episodes=300).first_episodes(100) == 100  # a specs file gives what it holds
    with pytest.raises(SpecError, match=r"--episodes must be in \[1, 100\] for linear-fast, got 101"):
        Selection("linear-fast", episodes=101).first_episodes(100, "linear-fast")
    with pytest.raises(SpecError, match="--episodes must be >= 1, got 0"):
        Selection(None, episodes=0).first_episodes(100)


def test_the_flags_and_the_python_options_give_the_same_spec(tmp_path):
    parser = make_parser("pipeline", "", pipeline_cli.COMMANDS)
    out = str(tmp_path / "run")
    args = parser.parse_args(["eval", "--policy", "still", "--slice", "linear-fast", "--episodes", "3", "--out", out,
                              "--workers", "1", "--resolution", "64", "--renderer", "window", "--formats", "parquet",
                              "--latency-frames", "2", "--quiet", "--overwrite"])
    protocol = job_flags.protocol_of(args)
    from_flags = job_flags.job_spec_of(args, args.slice, PolicyChoice("still", protocol=protocol))
    from_options = job_spec("linear-fast", out, {
        "episodes": 3, "workers": 1, "resolution": 64, "renderer": "window", "formats": "parquet", "progress": False,
        "overwrite": True, "protocol": EvalProtocol(latency_frames=2)}, shard_size=32, policy_ref="still")
    assert from_flags == from_options
    assert from_flags.settings.dataset_version == "5.0.0" and from_flags.settings.formats == ("parquet",)


def test_an_option_a_call_does_not_take_is_a_type_error(tmp_path):
    with pytest.raises(TypeError, match="unexpected keyword argument 'deadline_s'"):
        job_spec("linear-fast", tmp_path, {"deadline_s": 1.0}, shard_size=128)


def test_a_url_storage_names_its_slice_inside_without_a_local_folder():
    storage = Storage("s3://bucket/prefix/").inside("linear-fast")
    assert storage.remote and storage.out == "s3://bucket/prefix/linear-fast"
    storage.refuse_export("build")  # nothing local is looked at
