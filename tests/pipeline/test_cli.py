"""The one CLI layer (schemas.cli) as users meet it through the three console scripts:
one-line errors, exit codes, --version, pipes and full devices."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from schemas.versions import CODE_VERSION

BIN = Path(sys.executable).parent


def run(*args: str, stdout=subprocess.PIPE) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / args[0]), *args[1:]], stdout=stdout, stderr=subprocess.PIPE, text=True, timeout=120)


@pytest.mark.parametrize(
    "args",
    [("pipeline",), ("pipeline", "build"), ("pipeline", "eval"), ("catalog",), ("catalog", "specs"), ("scoring", "eval")],
)
def test_version_everywhere(args):
    result = run(*args, "--version")
    assert result.returncode == 0, result.stderr
    assert f"dyana {CODE_VERSION}" in result.stdout


@pytest.mark.parametrize(
    "args",
    [
        ("pipeline", "build", "--slice", "linear-fast", "--episodes", "0"),
        ("pipeline", "eval", "--policy", "still", "--out", "x", "--episodes", "0"),
        ("catalog", "stats", "linear-fast", "--episodes", "0"),
        ("catalog", "specs", "linear-fast", "--episodes", "0"),
    ],
)
def test_episodes_zero_is_refused_alike_by_every_command(args):
    result = run(*args)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1
    assert "argument --episodes: expected a number >= 1, got '0'" in result.stderr


@pytest.mark.parametrize("prog", ["pipeline", "catalog", "scoring"])
def test_usage_errors_are_one_line_with_the_program_named(prog):
    result = run(prog, "no-such-command")
    assert result.returncode == 2
    assert result.stderr.startswith(f"{prog}: error: ") and result.stderr.count("\n") == 1


def test_a_huge_bad_value_gives_a_short_line():
    result = run("pipeline", "build", "--slice", "x" * 100_000, "--episodes", "1")
    assert result.returncode == 2
    assert len(result.stderr) < 1000 and "100,000 characters" in result.stderr


def test_a_reader_that_goes_away_is_no_traceback():
    shell = f"{BIN / 'catalog'} specs linear-fast --episodes 2000 | head -1"
    result = subprocess.run(["bash", "-o", "pipefail", "-c", shell], capture_output=True, text=True, timeout=120)
    assert result.stdout.count("\n") == 1
    assert result.stderr == ""
    assert result.returncode == 141


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
@pytest.mark.parametrize("args", [("catalog", "list"), ("catalog", "specs", "test-1k", "--episodes", "50")])
def test_a_full_stdout_is_one_line_and_exit_2(args):
    with open("/dev/full", "w") as full:
        result = run(*args, stdout=full)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "No space left on device" in result.stderr
    assert "Traceback" not in result.stderr and "Exception ignored" not in result.stderr


@pytest.mark.parametrize(
    "args",
    [
        ("pipeline", "build", "--slice", "linear-fast", "--episodes", "2"),
        ("pipeline", "eval", "--policy", "still", "--slice", "linear-fast", "--episodes", "2"),
        ("catalog", "export", "nowhere"),
    ],
)
def test_an_out_name_that_is_not_utf8_is_refused_in_one_line(args, tmp_path):
    bad = bytes(tmp_path) + b"/bad\xffname"
    argv = [str(BIN / args[0]).encode(), *(a.encode() for a in args[1:]), b"--out", bad]
    result = subprocess.run(argv, capture_output=True, timeout=120)
    stderr = result.stderr.decode("utf-8", "replace")
    assert result.returncode == 2, stderr
    assert stderr.count("\n") == 1 and "Traceback" not in stderr
    assert "argument --out: expected a name in UTF-8" in stderr and "bad\\udcffname" in stderr
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("args", [
    ["pipeline", "build", "--slice", "linear-fast", "--episodes", "1", "--out", ""],
    ["pipeline", "eval", "--policy", "still", "--slice", "linear-fast", "--episodes", "1", "--out", ""],
    ["catalog", "export", "no-such-source", "--out", ""],
])
def test_an_empty_out_is_refused_not_taken_as_the_current_folder(args, tmp_path):
    """Before: --out '' (an unset shell variable) built into ./linear-fast, reporting
    '-> /linear-fast/catalog.json', and an eval wrote its run into the current folder."""
    result = subprocess.run([str(BIN / args[0]), *args[1:]], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 2 and "out must be a folder or file name (str or path-like), got ''" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and list(tmp_path.iterdir()) == []


def _subparser(command: str):
    from pipeline.cli import COMMANDS
    from schemas.cli import make_parser

    parser = make_parser("pipeline", "", COMMANDS)
    sub = next(a for a in parser._actions if a.dest == "command")
    return {a.dest: a for a in sub.choices[command]._actions}


def test_the_policy_and_protocol_options_are_the_registries():
    """--policy's help lists the registered policy kinds (serve's: those it can serve), and
    --protocol's choices are the wires' names: a new kind or wire needs no CLI edit."""
    from pipeline.policy_registry import KINDS, policy_help
    from pipeline.remote.wires import PROTOCOLS

    eval_options, serve_options = _subparser("eval"), _subparser("serve")
    assert eval_options["policy"].help == policy_help()
    assert all(kind.form in policy_help() for kind in KINDS) and "openpi:ws://HOST:PORT" in policy_help()
    assert serve_options["policy"].help == policy_help(servable=True) == (
        "oracle, still, chase, predictive, module:callable, lerobot:PATH (a LeRobot checkpoint folder, run with the "
        "lerobot installed here) or sb3:MODEL.zip (a saved Stable-Baselines3 model (sb3:ALGO:MODEL.zip names its "
        "algorithm))")
    assert serve_options["protocol"].choices == tuple(PROTOCOLS) == ("dyana", "openpi")
    flags = {dest for kind in KINDS for dest in kind.flags}
    assert flags and flags <= set(eval_options)  # every kind's flags are eval's options
