"""Every group of tests the default run leaves out is run by a step of ``.ci/run``, unless it
is one of the documented opt-ins: leaving a marker out of the default run must not leave it
out of CI (the manual's pages, the real peers, the separate hosts)."""

from __future__ import annotations

import re
import shlex
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Left out of CI on purpose, each saying so in its marker's description in pyproject.toml:
#: ``slow`` repeats a faster test, ``lerobot_real`` takes CPU hours in venvs of its own.
OPT_IN = {"slow", "lerobot_real"}


def _markers_of(expression: str) -> set[str]:
    return set(re.findall(r"[A-Za-z_]\w*", expression)) - {"not", "and", "or"}


def _negated(expression: str) -> set[str]:
    """The markers a ``-m`` expression names after ``not``."""
    return set(re.findall(r"\bnot\s+([A-Za-z_]\w*)", expression))


def default_run_leaves_out(pyproject: Path) -> set[str]:
    """The markers the default run's ``-m 'not a and not b ...'`` deselects."""
    addopts = shlex.split(tomllib.loads(pyproject.read_text(encoding="utf-8"))["tool"]["pytest"]["ini_options"]["addopts"])
    expression = addopts[addopts.index("-m") + 1]
    return _negated(expression)


def ci_selects(script: Path) -> set[str]:
    """The markers some pytest command of the script selects (``-m EXPR`` terms not negated)."""
    selected: set[str] = set()
    for line in script.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith("#") or "pytest" not in line:
            continue
        words = shlex.split(line, comments=True)
        for i, word in enumerate(words[:-1]):
            if word == "-m":
                expression = words[i + 1]
                selected |= _markers_of(expression) - _negated(expression)
    return selected


def test_every_marker_the_default_run_leaves_out_runs_in_ci_or_is_an_opt_in() -> None:
    left_out = default_run_leaves_out(ROOT / "pyproject.toml")
    assert {"manual", "peer", "multihost"} <= left_out, left_out
    assert left_out - OPT_IN - ci_selects(ROOT / ".ci" / "run") == set()


def test_a_marker_left_out_of_both_is_found(tmp_path: Path) -> None:
    (tmp_path / "pyproject.toml").write_text(
        "[tool.pytest.ini_options]\naddopts = \"-n 2 -m 'not slow and not manual and not peer'\"\n")
    (tmp_path / "run").write_text("# pytest -m manual (a comment)\n.venv/bin/python -m pytest -q -m 'peer and not slow'\n")
    assert default_run_leaves_out(tmp_path / "pyproject.toml") - OPT_IN - ci_selects(tmp_path / "run") == {"manual"}
