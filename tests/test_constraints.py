"""The lock (.ci/constraints.txt, written by .ci/lock.py): it pins every distribution the
project and its test and docs extras need, pyproject.toml's ranges admit every pin, and the
README's install command and .ci/run install with it."""

from __future__ import annotations

import importlib.util
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parent.parent
LOCK = ROOT / ".ci" / "constraints.txt"


def _lock_module():
    spec = importlib.util.spec_from_file_location("dyana_lock", ROOT / ".ci" / "lock.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


lock = _lock_module()


def _project_requirements() -> dict[str, list[Requirement]]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    groups = {"": project["dependencies"], **project["optional-dependencies"]}
    return {group: [Requirement(line) for line in lines] for group, lines in groups.items()}


def test_the_lock_is_canonical_exact_pins():
    pins = lock.read_lock(LOCK)
    assert pins, "no pins"
    assert list(pins) == sorted(pins)
    for name, version in pins.items():
        assert name == canonicalize_name(name), name
        assert str(Version(version)) == version, (name, version)


def test_the_lock_covers_every_installed_distribution_of_the_extras():
    """Every distribution `dyana[test,docs]` (and torch, when installed) needs here, transitive
    ones included, is pinned; a new dependency means rerunning .ci/lock.py."""
    pins = lock.read_lock(LOCK)
    needed = lock.closure()
    missing = sorted(set(needed) - set(pins))
    assert not missing, f"not in .ci/constraints.txt (rerun python3 .ci/lock.py): {missing}"
    assert "numpy" in needed and "mkdocs" in needed and "pytest" in needed  # the walk follows the extras


def test_pyproject_ranges_admit_every_pin():
    pins = lock.read_lock(LOCK)
    refused = []
    for group, requirements in _project_requirements().items():
        for req in requirements:
            pinned = pins.get(canonicalize_name(req.name))
            if group in ("", *lock.EXTRAS):
                assert pinned is not None, f"{req.name} ({group or 'core'}) is not pinned"
            if pinned is not None and not req.specifier.contains(pinned, prereleases=True):
                refused.append(f"{req} (pinned {pinned})")
    assert not refused, f"pyproject.toml's ranges refuse pins: {refused}"


def test_the_byte_determining_distributions_are_pinned():
    from catalog.store.versions import BYTE_DISTRIBUTIONS

    pins = lock.read_lock(LOCK)
    assert [name for name in BYTE_DISTRIBUTIONS if canonicalize_name(name) not in pins] == []


@pytest.mark.parametrize("path, needle", [
    ("README.md", ".venv/bin/pip install -c .ci/constraints.txt -e ."),
    (".ci/run", "pip install -q -c .ci/constraints.txt -e '.[test,docs]'"),
    (".ci/run", "pip install -q -c .ci/constraints.txt torch==2.13.0"),
    (".ci/run", "\n.ci/wheel-check\n"),
    (".ci/wheel-check", 'install -q --no-compile -c "$ROOT/.ci/constraints.txt" "$wheel"'),
])
def test_the_documented_installs_use_the_lock(path, needle):
    assert needle in (ROOT / path).read_text(encoding="utf-8")


def test_read_lock_refuses_a_line_that_is_no_pin(tmp_path):
    (tmp_path / "c.txt").write_text("# a comment\nnumpy==2.1.0\n\npyarrow>=15\n")
    with pytest.raises(ValueError, match=r"c.txt:4: not NAME==VERSION: 'pyarrow>=15'"):
        lock.read_lock(tmp_path / "c.txt")
