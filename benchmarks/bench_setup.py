"""Shared set-up of the benchmark scripts. Import it first, as ``import bench_setup``.

Importing it puts the repository's root first on ``sys.path`` (so a clone runs its own
code even where another Dyana is installed) and keeps the benchmarks folder on the path
last, because Dask's spawned worker processes re-run the script's imports, this one
included.
"""

from __future__ import annotations

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path[:] = [ROOT] + [p for p in sys.path if os.path.abspath(p or os.curdir) not in (HERE, ROOT)] + [HERE]


def pin_one_core() -> str:
    """Pin this process to one core, so single-core numbers mean one core."""
    if hasattr(os, "sched_setaffinity"):
        core = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {core})
        return f"pinned to core {core}"
    return "not pinned (no sched_setaffinity)"


#: The bare baseline's fixed work: a sum of squares in plain Python (no library, no I/O).
PROBE_TERMS = 10_000_000


def bare_probe(repeats: int = 3) -> float:
    """CPU seconds this machine takes for :data:`PROBE_TERMS` of plain-Python arithmetic, the
    fastest of ``repeats``: the bare baseline that a timing run records beside its numbers,
    since this machine's speed moves by 20-40% between runs at the same load."""
    import time

    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        sum(i * i for i in range(PROBE_TERMS))
        best = min(best, time.process_time() - start)
    return round(best, 3)


def machine_cpu() -> dict[str, float] | None:
    """This machine's CPU seconds since boot, all cores together (``psutil.cpu_times``, which
    Dask requires; on Linux it reads ``/proc/stat``): ``busy`` (user, nice, system,
    interrupts), ``idle`` (idle and I/O wait) and ``steal`` (time the hypervisor gave this
    virtual machine's cores to others, a load of the host's that ``uptime`` does not show).
    A host that slows the cores without taking them away shows in :func:`bare_probe`, not
    here. None where the system reports no steal (not Linux)."""
    import psutil

    times = psutil.cpu_times()
    if not hasattr(times, "steal"):
        return None
    busy = times.user + times.nice + times.system + times.irq + times.softirq
    return {"busy": busy, "idle": times.idle + times.iowait, "steal": times.steal}


def cpu_between(start: dict[str, float] | None, end: dict[str, float] | None) -> dict[str, float] | None:
    """What the machine did between two :func:`machine_cpu` readings, in CPU seconds."""
    if start is None or end is None:
        return None
    return {f"{key}_cpu_s": round(end[key] - start[key], 1) for key in ("busy", "idle", "steal")}


def provenance() -> dict:
    """What a result file records about where its numbers come from: the commit (and whether
    the working tree differed from it), the dataset version, the date, the cores and the load."""
    import subprocess
    import time

    from schemas.versions import DATASET_VERSION

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True).stdout.strip()

    return {"commit": git("rev-parse", "HEAD"), "tree_changed": bool(git("status", "--porcelain", "--untracked-files=no")),
            "dataset_version": DATASET_VERSION, "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
            "cores": os.cpu_count(), "load_average": [round(x, 2) for x in os.getloadavg()]}
