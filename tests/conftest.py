"""Test-session settings shared by every test folder.

One thread per math library, set before numpy or torch is imported: the suite runs on two
xdist workers (plus the processes tests start), and a torch or OpenMP pool left spinning
after a test that trained a model (SB3's PPO, a LeRobot-style policy) otherwise takes a
core from the other worker. Dyana's own workers are single-threaded too; a user's
environment still decides for their runs (a variable already set is kept).

One bytecode cache for the session: the tests start hundreds of Python processes (CLI
commands, Dask workers, policy servers, docs pages), and where the machine sets
``PYTHONDONTWRITEBYTECODE`` each of them compiled every Dyana module it imports again (6%
of the suite's CPU, measured). The xdist workers and every process they start write and
read compiled modules under one temporary ``PYTHONPYCACHEPREFIX`` (the checkout gets no
``__pycache__``), removed when the session ends. Python reads compiled modules only under
the prefix once one is set, so the stdlib's and the venv's own compiled files would be hidden
and each test process would compile every third-party module it imports (torch, pandas,
scipy: some 2,400 at collection, in both xdist workers at once): in the test processes a
finder first links a module's own compiled file into the cache before it is loaded
(:class:`LinkCompiled`); Python still checks it against its source, and writes a new file in
place of a stale link.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from importlib.machinery import PathFinder
from importlib.util import cache_from_source
from pathlib import Path

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

#: The session's bytecode cache, made by the process that starts the workers (they inherit it).
PYCACHE_OWNER = "DYANA_TEST_PYCACHE"
if PYCACHE_OWNER not in os.environ and "PYTHONPYCACHEPREFIX" not in os.environ:
    os.environ["PYTHONPYCACHEPREFIX"] = os.environ[PYCACHE_OWNER] = tempfile.mkdtemp(prefix="dyana-pycache-")
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)


class LinkCompiled:
    """A meta path finder that finds nothing: for a module about to be imported, it links the
    compiled file beside its source (``__pycache__/``) to where the session's cache keeps it."""

    tag = f".{sys.implementation.cache_tag}.pyc"

    def find_spec(self, name, path=None, target=None):
        spec = PathFinder.find_spec(name, path)
        origin = spec.origin if spec is not None else None
        if origin and origin.endswith(".py"):
            source = Path(origin)
            own = source.parent / "__pycache__" / (source.stem + self.tag)
            cached = Path(cache_from_source(origin))
            if own.is_file() and not cached.exists():
                try:
                    cached.parent.mkdir(parents=True, exist_ok=True)
                    cached.symlink_to(own)
                except OSError:  # another process linked it first, or the cache cannot hold it: Python compiles
                    pass
        return None


if sys.pycache_prefix is not None and sys.pycache_prefix == os.environ.get(PYCACHE_OWNER):
    sys.meta_path.insert(0, LinkCompiled())


def pytest_unconfigure(config) -> None:
    """The session's first process removes the cache it made (the workers inherited its name)."""
    if not hasattr(config, "workerinput") and os.environ.get(PYCACHE_OWNER) == os.environ.get("PYTHONPYCACHEPREFIX"):
        shutil.rmtree(os.environ[PYCACHE_OWNER], ignore_errors=True)
