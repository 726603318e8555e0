"""Fixtures of the docs runner: one build cache, one ``pipeline`` shim, and pages run three
at a time in processes of their own (each test waits for its page's process)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.docs import build_cache
from tests.docs.pages import ROOT

#: Pages run side by side, three on two cores: each waits on its commands' processes part of
#: the time, and three keep both cores busy (the manual's pages in 57.8 s, 7.6 idle CPU s; two
#: at a time: 66.2 s, 17.9 idle).
CONCURRENT_PAGES = 3
#: How often a waiting test looks for pages that ended (their output is small: no pipe fills).
POLL_S = 0.05


@dataclass(frozen=True)
class PageResult:
    """A page's run: its exit code, the blocks it did not run (with why), its error output."""

    returncode: int
    skipped: list[str]
    error: str


class PagePool:
    """Starts page processes ahead of the tests that wait for them, a few at a time."""

    def __init__(self, order: list[tuple[str, bool]], root: Path, env: dict[str, str]) -> None:
        self.order, self.root, self.env = order, root, env
        self.running: dict[tuple[str, bool], subprocess.Popen[str]] = {}
        self.done: dict[tuple[str, bool], PageResult] = {}

    def _start_more(self) -> None:
        for case in self.order:
            if sum(p.poll() is None for p in self.running.values()) >= CONCURRENT_PAGES:
                return
            if case not in self.running and case not in self.done:
                path, with_slow = case
                folder = self.root / f"{len(self.running):03d}" / "page"
                folder.mkdir(parents=True)
                argv = [sys.executable, "-m", "tests.docs.runner", path, str(folder), *(["--with-slow"] * with_slow)]
                self.running[case] = subprocess.Popen(argv, cwd=ROOT, env=self.env, text=True,
                                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    def result(self, path: str, with_slow: bool) -> PageResult:
        case = (path, with_slow)
        if case not in self.order:
            self.order.append(case)
        while case not in self.done:
            self._start_more()
            # Every page that ends is collected at once and its slot refilled, whichever
            # page this test waits for: no core idles behind a longer page.
            for running, process in list(self.running.items()):
                if running not in self.done and process.poll() is not None:
                    self._collect(running)
            if case not in self.done:
                time.sleep(POLL_S)
        self._start_more()
        return self.done[case]

    def _collect(self, case: tuple[str, bool]) -> None:
        process = self.running[case]
        out, err = process.communicate()
        lines = out.strip().splitlines()
        skipped = json.loads(lines[-1]) if process.returncode == 0 and lines else []
        self.done[case] = PageResult(process.returncode, skipped, err)

    def close(self) -> None:
        """Stop the pages still running (SIGTERM: each ends the processes its blocks started)."""
        for process in self.running.values():
            if process.poll() is None:
                process.terminate()
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()


def _build_cache_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """This session's build cache. Under pytest-xdist the test processes share one (their
    temporary folders are siblings in the session's), so a page's build made by one is a
    copy for the other; the cache stores an entry by renaming a finished folder, so two
    processes building the same command at once both succeed."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = tmp_path_factory.getbasetemp().parent / "docs-build-cache"
        shared.mkdir(exist_ok=True)
        return shared
    return tmp_path_factory.mktemp("docs-build-cache")


@pytest.fixture(scope="session")
def page_pool(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):
    """The pages the selected tests run, started in their collection order."""
    venv_bin = Path(sys.executable).parent
    real = shutil.which("pipeline", path=str(venv_bin)) or shutil.which("pipeline")
    if real is None:
        pytest.fail("the `pipeline` command is not installed: pip install -e . first")
    shim_dir = tmp_path_factory.mktemp("docs-bin")
    extra = build_cache.install(shim_dir, _build_cache_folder(tmp_path_factory), real, ROOT)
    env = {**os.environ, **extra, "PATH": os.pathsep.join([str(shim_dir), str(venv_bin), os.environ.get("PATH", "")])}
    order = [(str(item.callspec.params["path"]), bool(item.callspec.params["with_slow"]))
             for item in request.session.items
             if isinstance(item, pytest.Function) and item.originalname == "test_page_runs"
             and hasattr(item, "callspec")]
    if os.environ.get("PYTEST_XDIST_WORKER"):
        # Under pytest-xdist every process collects every page but runs only those it is
        # given: starting pages ahead would run the other process's pages a second time.
        order = []
    pool = PagePool(order, tmp_path_factory.mktemp("docs-pages"), env)
    yield pool
    pool.close()
