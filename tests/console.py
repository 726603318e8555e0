"""A Dyana command run in the test process through its entry point, as its console script
runs it: a process each costs its start (mostly imports), so tests that check a command's
result call this, and each file keeps a real process for a refusal's one-line stderr."""

from __future__ import annotations

import subprocess


def run_here(capsys, program: str, *args: object) -> subprocess.CompletedProcess:
    """``program`` (``pipeline``, ``catalog`` or ``scoring``) with ``args``: its exit status and
    what it printed, read with pytest's ``capsys`` (cleared first)."""
    from pipeline.cli import main as pipeline_main
    from pipeline.cli_catalog import main as catalog_main
    from scoring.cli import main as scoring_main

    mains = {"pipeline": pipeline_main, "catalog": catalog_main, "scoring": scoring_main}
    argv = [str(a) for a in args]
    capsys.readouterr()
    code = mains[program](argv)
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess([program, *argv], code, out, err)
