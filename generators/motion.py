"""Motion tokens evaluated in closed form (the public face of four modules:
:mod:`generators.tracks`, :mod:`generators.segments`, :mod:`generators.rolling`,
:mod:`generators.bounds`; each token type's closed forms are one class in
:mod:`generators.primitives`): r(t), v(t), a(t), curvature and arc length,
the target's 7-DoF pose with no-slip rolling, and cheap XZ bounds (paper 3.1, A.6).

Semantics are those of :mod:`schemas.motion`: each token runs on local time since its
own start; a later token is translated to begin where the previous one ended; a
clothoid after another token inherits its end position, heading, speed and curvature;
an overlay adds its displacement since its own start on ``[start, end]`` and holds it
after ``end``. At a join the later token's velocity and acceleration apply.

Times are seconds since the motion's start. Negative times raise :class:`SpecError`.
Past the base track's end the last token's closed form is *extrapolated*, not clamped,
so position, velocity and acceleration stay mutually consistent (the recipe always
makes motions long enough; this is only a safety net).

Every function here is pure and deterministic. Path-dependent quantities (a rolling
sphere's orientation on curved paths, a lying cylinder's heading under overlays) are
integrated on a fixed grid of :data:`ROLL_STEP_S` anchored at each segment's start,
so a time's result does not depend on which other times are asked for.
"""

from __future__ import annotations

from generators.bounds import motion_bounds
from generators.rolling import object_angular_velocity, object_orientation, object_pose
from generators.segments import arc_length
from generators.tracks import ROLL_STEP_S, ZERO_SPEED, MotionSample, curvature, evaluate
from schemas.rotations import qmul

__all__ = [
    "ROLL_STEP_S",
    "ZERO_SPEED",
    "MotionSample",
    "arc_length",
    "curvature",
    "evaluate",
    "motion_bounds",
    "object_angular_velocity",
    "object_orientation",
    "object_pose",
    "qmul",
]
