"""pybullet, imported without its build-time banner, and its physics-only clients.

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


def physics_client() -> int:
    """A DIRECT client for collision queries and dynamics only. Its TinyRenderer plugin is
    unloaded: with it, every body made without a visual shape gets one converted from its
    collision shapes (a convex hull per capsule), which is most of a hold test's set-up and
    changes no contact, force or pose (the hold test's results are the same bit for bit, tested)."""
    client = p.connect(p.DIRECT)
    renderer = p.loadPlugin("tinyRendererPlugin", physicsClientId=client)  # the id of the one already loaded
    if renderer >= 0:
        p.unloadPlugin(renderer, physicsClientId=client)
    return client
