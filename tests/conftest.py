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
``__pycache__``), removed when the session ends.
"""

from __future__ import annotations

import os
import shutil
import tempfile

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

#: The session's bytecode cache, made by the process that starts the workers (they inherit it).
PYCACHE_OWNER = "DYANA_TEST_PYCACHE"
if PYCACHE_OWNER not in os.environ and "PYTHONPYCACHEPREFIX" not in os.environ:
    os.environ["PYTHONPYCACHEPREFIX"] = os.environ[PYCACHE_OWNER] = tempfile.mkdtemp(prefix="dyana-pycache-")
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)


def pytest_unconfigure(config) -> None:
    """The session's first process removes the cache it made (the workers inherited its name)."""
    if not hasattr(config, "workerinput") and os.environ.get(PYCACHE_OWNER) == os.environ.get("PYTHONPYCACHEPREFIX"):
        shutil.rmtree(os.environ[PYCACHE_OWNER], ignore_errors=True)
