"""The paper's two events, defined once (paper A.5).

*Localization*: the palm centre is within :data:`~schemas.scene.LOC_TOLERANCE` of the
object's centre in the XZ (table) plane; for an object that flies (a projectile, paper
A.11), within that distance in 3D of the hover point above its top (the object's centre
raised by :func:`hover_offset`), so a palm under or far above a flying object is not
over it. *Grasp*: every finger joint has reached
:data:`~schemas.scene.GRASP_RATIO` of the episode's ground-truth grasp angles.

The closed-loop environment (which labels phases and ends an episode on grasp), the
evaluation's quick counts and every metric in :mod:`scoring` call these functions, so
an episode localizes in the loop exactly when its recording scores as localized under
``scoring``'s ``lenient`` reading; its default ``paper`` reading also asks for the palm
above the object's top (:func:`scoring.metrics.above_top`), which the loop's phase labels
do not.
Inputs are converted to float64 first: recorded float32 values give the same decision
wherever they are read.
"""

from __future__ import annotations

import numpy as np

from schemas.objects import object_category
from schemas.scene import GRASP_CONTACT_TOLERANCE, GRASP_RATIO, LOC_TOLERANCE, PALM_HOVER, PHASES
from schemas.spec import EpisodeSpec, acting_horizon

OBSERVE = PHASES.index("observe")


def palm_xz_distance(palm_xyz: np.ndarray, object_xyz: np.ndarray) -> np.ndarray:
    """Distance in the XZ plane between the palm centre and the object's centre, (...,)."""
    palm = np.asarray(palm_xyz, dtype=np.float64)
    obj = np.asarray(object_xyz, dtype=np.float64)
    return np.hypot(palm[..., 0] - obj[..., 0], palm[..., 2] - obj[..., 2])


#: Substring of a motion's canonical JSON (the ``tokens`` column) that marks a flight.
PROJECTILE_MARK = '"type":"P"'


def hover_offset(object_name: str, object_size: float, airborne: bool) -> float:
    """Height of the hover point above the object's centre (its top plus the palm's hover
    height) for a flying object; NaN for one on the table (localized in XZ)."""
    if not airborne:
        return float("nan")
    return object_category(object_name).half_height(object_size) + PALM_HOVER


def spec_hover_offset(spec: EpisodeSpec) -> float:
    return hover_offset(spec.object, spec.object_size, spec.motion.airborne)


def palm_distance(palm_xyz: np.ndarray, object_xyz: np.ndarray, offset=None) -> np.ndarray:
    """The localization distance, (...,): the palm's XZ distance to the object's centre,
    or where ``offset`` (scalar or (...,), :func:`hover_offset`) is not NaN the palm's 3D
    distance to the hover point ``object + (0, offset, 0)``."""
    d_xz = palm_xz_distance(palm_xyz, object_xyz)
    if offset is None:
        return d_xz
    off = np.broadcast_to(np.asarray(offset, dtype=np.float64), d_xz.shape)
    dy = np.asarray(palm_xyz, dtype=np.float64)[..., 1] - np.asarray(object_xyz, dtype=np.float64)[..., 1] - off
    with np.errstate(invalid="ignore"):
        return np.where(np.isnan(off), d_xz, np.hypot(d_xz, dy))


def within_tolerance(distance: np.ndarray) -> np.ndarray:
    """Whether a palm XZ distance counts as localized."""
    return np.asarray(distance) <= LOC_TOLERANCE


def localized(palm_xyz: np.ndarray, object_xyz: np.ndarray, offset=None) -> np.ndarray:
    """Whether the palm is over the object (per frame, (...,) bool); ``offset`` as for
    :func:`palm_distance`."""
    return within_tolerance(palm_distance(palm_xyz, object_xyz, offset))


def grasp_closed(joint_angles: np.ndarray, grasp_angles: np.ndarray) -> np.ndarray:
    """Whether every joint reached ``GRASP_RATIO`` of its grasp angle (per frame, (...,) bool).

    ``joint_angles`` (..., 15) broadcasts against ``grasp_angles`` (15,) or (..., 15).
    """
    joints = np.asarray(joint_angles, dtype=np.float64)
    grasp = np.asarray(grasp_angles, dtype=np.float64)
    return np.all(joints >= GRASP_RATIO * grasp, axis=-1)


def touching(fingertip_distance: np.ndarray) -> np.ndarray:
    """Whether the closest fingertip is within the contact tolerance of the object's surface."""
    return np.asarray(fingertip_distance, dtype=np.float64) <= GRASP_CONTACT_TOLERANCE


def contact_grasp(localized_now: np.ndarray, closed_now: np.ndarray, fingertip_distance: np.ndarray) -> np.ndarray:
    """Dyana's contact-grounded grasp, per frame: the joint criterion, the palm localized
    and a fingertip touching the object's surface, all at the same frame, so a fist closed
    away from the object never counts, unlike the joint-only S_gra. (Paper A.8 asks for a
    fingertip near the object's centre only: the joint and palm conjuncts are Dyana's.)"""
    return np.asarray(localized_now) & np.asarray(closed_now) & touching(fingertip_distance)


def acting(phase: np.ndarray) -> np.ndarray:
    """Which frames are acting frames (every phase but ``observe``), from phase codes."""
    return np.asarray(phase) != OBSERVE


def acting_budget(num_frames, observe_frames, rollout: bool, recorded):
    """R_time's N: the acting frames an episode could last.

    A ground-truth episode lasts what it recorded; a rollout stops at grasp completion,
    so its N is the acting horizon it was allowed (else R_time would always be 0).
    Works on ints or numpy integer arrays.
    """
    if not rollout:
        return recorded
    return acting_horizon(num_frames, observe_frames)
