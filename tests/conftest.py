"""Test-session settings shared by every test folder.

One thread per math library, set before numpy or torch is imported: the suite runs on two
xdist workers (plus the processes tests start), and a torch or OpenMP pool left spinning
after a test that trained a model (SB3's PPO, a LeRobot-style policy) otherwise takes a
core from the other worker. Dyana's own workers are single-threaded too; a user's
environment still decides for their runs (a variable already set is kept).
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
