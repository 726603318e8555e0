"""A separate virtual environment holding one pinned third-party package, for tests that
talk to the real library as a peer (openpi-client pins numpy<2, which Dyana's pyarrow
cannot share). Built once per package version under ~/.cache/dyana/peer-venvs
(``DYANA_PEER_VENVS`` moves it) and reused; a failed build fails the test (no skip)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

#: Seconds a build may take (pip from PyPI: 90-145 s measured with a warm pip cache on 2 busy cores).
BUILD_TIMEOUT_S = 900


def peer_venvs() -> Path:
    return Path(os.environ.get("DYANA_PEER_VENVS") or Path.home() / ".cache" / "dyana" / "peer-venvs")


def peer_python(package: str, version: str, also: tuple[str, ...] = ()) -> Path:
    """The python of the venv holding ``package==version`` and the requirements ``also``
    (what the package imports but does not declare), built now if missing or made with other
    requirements; the build's seconds go to stderr."""
    folder = peer_venvs() / f"{package}-{version}"
    python = folder / "bin" / "python"
    wanted = " ".join((f"{package}=={version}", *also)) + "\n"
    done = folder / ".complete"
    if done.exists() and done.read_text() == wanted:
        return python
    shutil.rmtree(folder, ignore_errors=True)
    base = sys.base_prefix + "/bin/python3" if Path(sys.base_prefix, "bin", "python3").exists() else "python3"
    building = folder.with_name(f"{folder.name}.building-{os.getpid()}")
    shutil.rmtree(building, ignore_errors=True)
    building.parent.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    try:
        subprocess.run([base, "-m", "venv", str(building)], check=True, capture_output=True, timeout=120)
        pip = subprocess.run([str(building / "bin" / "python"), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                              f"{package}=={version}", *also], capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
        if pip.returncode != 0:
            pytest.fail(f"cannot build the {package}=={version} peer venv: {pip.stderr.strip()[-800:]}")
        (building / ".complete").write_text(wanted)
        try:
            building.rename(folder)  # a venv runs from its new place with `bin/python` (scripts' shebangs aside)
        except OSError:  # built meanwhile by another run: keep that one
            if not done.exists():
                raise
    finally:
        shutil.rmtree(building, ignore_errors=True)
    print(f"built the {package}=={version} peer venv in {time.monotonic() - start:.0f} s", file=sys.stderr)
    return python
