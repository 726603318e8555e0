"""The wheel holds every module and every data file the code reads at run time.

An editable install (CI's, the README's) imports from the checkout and hides a package
left out of the wheel; this builds the wheel from a clean copy of the source and looks
inside it. (.ci/wheel-check installs that wheel in a fresh venv and runs the commands.)
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("schemas", "generators", "catalog", "pipeline", "scoring")
# Build products and caches: never in the copy, or a stale build/lib could fill the wheel.
IGNORED = shutil.ignore_patterns(".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", "*.pyc", "*.rrd",
                                 ".mypy_cache", ".pytest_cache", ".hypothesis", ".ruff_cache", ".import_linter_cache",
                                 ".train-data", "site", "out", "runs")


def _source_files() -> list[str]:
    """Every file under the five packages, as a path relative to the checkout."""
    files = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*")):
            if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc":
                files.append(path.relative_to(ROOT).as_posix())
    return files


def _loaded_data_files() -> list[str]:
    """The data files the code opens beside its modules (the constants it opens them by)."""
    from catalog.store.footprint import FOOTPRINT_PATH
    from pipeline.policies.blind import PATH_FILE
    from pipeline.policies.vlm import TEMPLATES

    paths = [FOOTPRINT_PATH, PATH_FILE, *sorted(TEMPLATES.glob("*.txt"))]
    return [path.resolve().relative_to(ROOT).as_posix() for path in paths]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    source = tmp_path_factory.mktemp("source") / "dyana"
    shutil.copytree(ROOT, source, ignore=IGNORED)
    out = tmp_path_factory.mktemp("wheel")
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out), str(source)],
        capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    (built,) = out.glob("dyana-*.whl")
    return built


@pytest.fixture(scope="module")
def wheel_names(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as archive:
        return set(archive.namelist())


def test_every_module_and_package_file_is_in_the_wheel(wheel_names: set[str]) -> None:
    missing = [name for name in _source_files() if name not in wheel_names]
    assert not missing, f"left out of the wheel: {missing}"


def test_every_loaded_data_file_is_in_the_wheel(wheel_names: set[str]) -> None:
    loaded = _loaded_data_files()
    assert "catalog/store/footprint.json" in loaded and "pipeline/policies/vlm_prompts/v1.txt" in loaded
    missing = [name for name in loaded if name not in wheel_names]
    assert not missing, f"read at run time but not in the wheel: {missing}"


def test_the_wheel_holds_only_the_five_packages(wheel_names: set[str]) -> None:
    tops = {name.split("/")[0] for name in wheel_names if not name.split("/")[0].endswith(".dist-info")}
    assert tops == set(PACKAGES)


def test_the_wheel_declares_the_entry_points(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as archive:
        (name,) = [n for n in archive.namelist() if n.endswith(".dist-info/entry_points.txt")]
        lines = set(archive.read(name).decode().splitlines())
    for line in ("pipeline = pipeline.cli:main", "catalog = pipeline.cli_catalog:main", "scoring = scoring.cli:main",
                 "Dyana = pipeline.loop.registration:register"):
        assert line in lines, (line, sorted(lines))
