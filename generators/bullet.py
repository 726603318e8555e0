"""pybullet, imported without its build-time banner.

pybullet's C module prints "pybullet build time: ..." on file descriptor 2 when it is
first imported, once per process: every build worker and test subprocess would repeat
it between the progress lines. Import it from here. (An import failure still raises.)
"""

from __future__ import annotations

import os
import sys


def _quiet_import():
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
    return pybullet


p = _quiet_import()
