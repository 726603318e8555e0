"""The manual run as a reader follows it: README's tour, Getting started, then every guide in
the site's order, all in one working folder with one environment (tests/docs/runner.py's
in-order mode). The per-page runs (test_pages.py) start each page in a fresh folder, so they
cannot see one page's folder refusing another's job (the Evaluate guide once wrote to
Getting started's ``runs/predictive``)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from tests.docs.pages import ROOT


def manual_order(root: Path = ROOT) -> list[str]:
    """README.md, Getting started, then the guides, in mkdocs.yml's nav order."""
    text = (root / "mkdocs.yml").read_text(encoding="utf-8")
    section = re.search(r"^nav:\n(?:[ \t].*\n?|\n)*", text, re.MULTILINE)  # the nav alone: other keys hold !!python tags
    assert section is not None, "mkdocs.yml has no nav"
    nav = yaml.safe_load(section.group(0))["nav"]
    pages = []

    def walk(entries: list) -> None:
        for entry in entries:
            for target in entry.values() if isinstance(entry, dict) else [entry]:
                if isinstance(target, list):
                    walk(target)
                elif isinstance(target, str) and (target == "getting-started.md" or target.startswith("guides/")):
                    pages.append(f"docs/{target}")

    walk(nav)
    return ["README.md", *pages]


def test_the_order_is_the_sites():
    order = manual_order()
    assert order[:2] == ["README.md", "docs/getting-started.md"]
    assert "docs/guides/evaluate.md" in order and len(order) >= 10


@pytest.mark.slow(cover="tests/docs/test_pages.py::test_page_runs")
def test_the_manual_runs_in_order(tmp_path):
    folder = tmp_path / "reader"
    folder.mkdir()
    venv_bin = Path(sys.executable).parent
    env = {**os.environ, "PATH": f"{venv_bin}{os.pathsep}{os.environ.get('PATH', '')}"}
    assert shutil.which("pipeline", path=str(venv_bin)), "pip install -e . first"
    done = subprocess.run([sys.executable, "-m", "tests.docs.runner", *manual_order(), str(folder), "--with-slow"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=3600)
    assert done.returncode == 0, done.stderr[-4000:]
