"""pybullet, imported without its build-time banner on standard output.

pybullet's C module prints "pybullet build time: ..." to file descriptor 1 when it is
first imported, which would pollute the stdout of commands that print data (JSON,
JSONL). Import it from here.
"""

from __future__ import annotations

import os
import sys


def _quiet_import():
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        import pybullet
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)
    return pybullet


p = _quiet_import()
