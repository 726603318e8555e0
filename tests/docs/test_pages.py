"""Every ```bash and ```python block of README.md and docs/**/*.md runs (the markers: pages.py).

One test per page (and a second, marked slow, for a page with ``slow`` blocks): its
blocks in page order in a fresh temporary folder, in a process of its own (runner.py);
a failure names the page and the block's line. Marked ``manual``: not in the default run;
``.ci/run`` runs them in a step of their own (``pytest -n 0 -m 'manual and not slow'
tests/docs``: the page pool runs several pages at once in one test process).
"""

from __future__ import annotations

import pytest

from tests.docs.conftest import PagePool
from tests.docs.pages import load, page_paths

pytestmark = pytest.mark.manual


def _cases() -> list:
    cases = []
    for path in page_paths():
        page = load(path)
        if not page.blocks and not page.setup:
            continue
        cases.append(pytest.param(path, False, id=path))
        if page.has_slow:
            cases.append(pytest.param(path, True, id=f"{path}[with slow blocks]", marks=pytest.mark.slow(cover="tests/docs/test_pages.py::test_page_runs")))
    return cases


@pytest.mark.parametrize("path,with_slow", _cases())
def test_page_runs(path: str, with_slow: bool, page_pool: PagePool) -> None:
    result = page_pool.result(path, with_slow)
    assert result.returncode == 0, result.error
    if result.skipped and len(result.skipped) == len(load(path).blocks):
        pytest.skip("no block ran: " + "; ".join(result.skipped))
