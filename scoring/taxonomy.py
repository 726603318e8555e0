"""Why did it fail? One class per episode, read off its recorded states alone.

An episode succeeds when its grasp holds the object (S_hold, the headline: the hold test
of :mod:`scoring.hold`); every other episode gets exactly one failure class. The first
rule that holds, in this order, names it (:data:`FAILURE_CLASSES`):

1. ``success``: the grasp held, status ``ok``, no obstacle touched (unless
   ``--obstacle-contact report``).
2. ``policy_error``: status ``error`` (the policy raised, hung, dropped its connection
   or returned a bad action); the recorded message says which.
3. ``obstacle_contact``: the hand touched an obstacle (smallest clearance <= 0). With
   ``--obstacle-contact report`` contact is only a flag (the collision rate, the
   per-episode ``obstacle_contact`` column), not a class.
4. ``not_held``: a contact grasp (S_grasp_contact: joints closed, palm localized, a
   fingertip on the surface at one frame) that the hold test dropped: the hand closed on
   the object but not around it.
5. ``no_motion``: the palm never moved more than :data:`NO_MOTION_DISPLACEMENT` (0.1
   units, 1 cm) from its position at the first acting frame (or there is no acting frame).
6. ``grasp_only``: the palm was localized (S_loc) but no frame had the contact grasp:
   the hand never closed, or closed away from the object or without touching it.
7. ``timing``: never localized, but the palm was within the localization tolerance of
   where the object was (or would be) up to :data:`CROSSING_WINDOW` (10) frames earlier or
   later: the right place at the wrong time (``crossing_offset`` says how early or late).
8. ``near_miss``: neither, but the palm came within :data:`NEAR_MISS_DISTANCE` (twice the
   tolerance, 0.6) of the object at the same frame: a small aiming error, whether from
   control or prediction (the states cannot tell them apart).
9. ``perception_prediction``: the palm went where the object never was within the window
   (same-frame distance always > 0.6, no crossing within 10 frames): it was aimed at the
   wrong place.

Distances are the localization distance of :func:`schemas.events.palm_distance`
(XZ, or 3D to the hover point of a flying object), palm at acting frame t against object
at acting frame t + offset of the same episode. Evidence per episode (:class:`Failures`):
``displacement``, ``path_miss`` (the smallest such distance over offsets within the
window: the palm's closest approach to the object's path) and ``crossing_offset`` (the
offset of smallest size at which the distance is within tolerance: the least shift in time
that would have localized; negative: the palm was late, the object had been there;
positive: early; 0: localized).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from schemas import events
from schemas.obstacles import CONTACT_CLEARANCE
from schemas.scene import LOC_TOLERANCE
from scoring.metrics import EpisodeMetrics

#: Classes in order of precedence; every episode gets exactly one.
FAILURE_CLASSES = (
    "success", "policy_error", "obstacle_contact", "not_held", "no_motion", "grasp_only", "timing", "near_miss",
    "perception_prediction",
)
#: A palm that never moves farther than this (units) from its first acting position did not move.
NO_MOTION_DISPLACEMENT = 0.1
#: Largest offset (frames, 0.5 s: the fast interception time) at which a crossing is a timing error.
CROSSING_WINDOW = 10
#: Same-frame distance (units) within which a miss is a near miss: twice the localization tolerance.
NEAR_MISS_DISTANCE = 2.0 * LOC_TOLERANCE


@dataclass(frozen=True)
class Failures:
    """Each episode's class (``failure``, names from :data:`FAILURE_CLASSES`) and its evidence.

    ``displacement``: the palm's largest distance from its first acting position (NaN without
    acting frames); ``path_miss``: the smallest palm-object distance over offsets within
    :data:`CROSSING_WINDOW` (NaN without acting frames); ``crossing_offset``: the offset of
    smallest size within tolerance (:func:`crossing`), valid where ``crossed``
    (``path_miss`` within the localization tolerance).
    """

    failure: np.ndarray
    displacement: np.ndarray
    path_miss: np.ndarray
    crossing_offset: np.ndarray
    crossed: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.failure)
        for name in ("displacement", "path_miss", "crossing_offset", "crossed"):
            shape = np.shape(getattr(self, name))
            if shape != (n,):
                raise ValueError(f"{name} must have shape ({n},), got {shape}")
        unknown = sorted(set(self.failure.tolist()) - set(FAILURE_CLASSES))
        if unknown:
            raise ValueError(f"unknown failure class {unknown[0]!r} (expected one of {list(FAILURE_CLASSES)})")

    def __len__(self) -> int:
        return len(self.failure)

    def counts(self, select: np.ndarray | None = None) -> dict[str, int]:
        """Episodes per class (all, or where ``select`` is true), every class listed, in precedence order."""
        names = self.failure if select is None else self.failure[np.asarray(select, dtype=bool)]
        return {name: int(np.count_nonzero(names == name)) for name in FAILURE_CLASSES}


def _owners(offsets: np.ndarray) -> np.ndarray:
    offsets = np.asarray(offsets, dtype=np.int64)
    if offsets.ndim != 1 or len(offsets) < 1 or offsets[0] != 0 or np.any(np.diff(offsets) < 0):
        raise ValueError(f"offsets must be non-decreasing from 0, got {offsets[:3]}...{offsets[-3:]}")
    return np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))


def max_displacement(offsets: np.ndarray, palm_xyz: np.ndarray) -> np.ndarray:
    """(n,) each episode's largest palm distance from its first acting position; NaN without frames."""
    palm = np.asarray(palm_xyz, dtype=np.float64)
    owner = _owners(offsets)
    if palm.shape != (len(owner), 3):
        raise ValueError(f"palm_xyz must have shape ({len(owner)}, 3), got {palm.shape}")
    n = len(offsets) - 1
    start = palm[np.asarray(offsets, dtype=np.int64)[:-1][owner]]
    out = np.full(n, -np.inf)
    np.maximum.at(out, owner, np.linalg.norm(palm - start, axis=1))
    return np.where(np.diff(offsets) > 0, out, np.nan)


def offset_distances(
    offsets: np.ndarray,
    palm_xyz: np.ndarray,
    object_xyz: np.ndarray,
    hover_offset: np.ndarray | None = None,
    window: int = CROSSING_WINDOW,
) -> np.ndarray:
    """(2 window + 1, n): row ``window + k`` holds each episode's smallest localization distance
    between the palm at acting frame t and the object at acting frame t + k (+inf where the
    episode has no such pair). Row ``window`` (k = 0) is E_loc."""
    if window < 0:
        raise ValueError(f"window must be >= 0 frames, got {window}")
    palm = np.asarray(palm_xyz, dtype=np.float64)
    obj = np.asarray(object_xyz, dtype=np.float64)
    owner = _owners(offsets)
    m, n = len(owner), len(offsets) - 1
    if palm.shape != (m, 3) or obj.shape != (m, 3):
        raise ValueError(f"palm_xyz and object_xyz must have shape ({m}, 3), got {palm.shape} and {obj.shape}")
    lift = np.full(n, np.nan) if hover_offset is None else np.asarray(hover_offset, dtype=np.float64)
    if lift.shape != (n,):
        raise ValueError(f"hover_offset must have shape ({n},), got {lift.shape}")
    out = np.full((2 * window + 1, n), np.inf)
    for row, k in enumerate(range(-window, window + 1)):
        t = np.arange(max(0, -k), m - max(0, k))
        t = t[owner[t] == owner[t + k]]
        if len(t):
            distance = events.palm_distance(palm[t], obj[t + k], lift[owner[t]])
            np.minimum.at(out[row], owner[t], distance)
    return out


def crossing(distances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(offset, crossed)`` per episode from :func:`offset_distances`: the offset of smallest
    size whose distance is within the localization tolerance (of two, the nearer, then the
    negative one: late); ``crossed`` is false (offset 0) when there is none."""
    distances = np.asarray(distances, dtype=np.float64)
    window = (len(distances) - 1) // 2
    within = events.within_tolerance(distances)
    size = np.where(within, np.abs(np.arange(-window, window + 1))[:, None], window + 1).min(axis=0)
    crossed = size <= window
    size = np.minimum(size, window)
    episodes = np.arange(distances.shape[1])
    late = np.where(within[window - size, episodes], distances[window - size, episodes], np.inf)
    early = np.where(within[window + size, episodes], distances[window + size, episodes], np.inf)
    return np.where(crossed, np.where(early < late, size, -size), 0).astype(np.int64), crossed


def classify(
    per: EpisodeMetrics,
    error: np.ndarray,
    displacement: np.ndarray,
    crossed: np.ndarray,
    min_clearance: np.ndarray | None = None,
    contact_fails: bool = True,
) -> np.ndarray:
    """(n,) each episode's class name, the first rule of the module docstring that holds."""
    n = len(per)
    error = np.asarray(error, dtype=bool)
    if error.shape != (n,):
        raise ValueError(f"error must have shape ({n},), got {error.shape}")
    touched = np.zeros(n, dtype=bool)
    if contact_fails and min_clearance is not None:
        touched = np.asarray(min_clearance, dtype=np.float64) <= CONTACT_CLEARANCE
    with np.errstate(invalid="ignore"):
        still = ~(np.asarray(displacement, dtype=np.float64) > NO_MOTION_DISPLACEMENT)
        near = per.e_loc <= NEAR_MISS_DISTANCE
    held = per.contact_grasped if per.t_hold is None else per.t_hold >= 0
    rules = (
        ("policy_error", error),
        ("obstacle_contact", touched),
        ("success", held),
        ("not_held", per.contact_grasped),
        ("no_motion", still),
        ("grasp_only", per.localized),
        ("timing", np.asarray(crossed, dtype=bool)),
        ("near_miss", near),
    )
    out = np.full(n, "perception_prediction", dtype=object)
    for name, holds in reversed(rules):
        out[holds] = name
    return out


def episode_failures(
    per: EpisodeMetrics,
    offsets: np.ndarray,
    palm_xyz: np.ndarray,
    object_xyz: np.ndarray,
    error: np.ndarray,
    hover_offset: np.ndarray | None = None,
    min_clearance: np.ndarray | None = None,
    contact_fails: bool = True,
) -> Failures:
    """Classes and evidence of ``n`` episodes (their acting frames, as for
    :func:`scoring.metrics.episode_metrics`, whose result ``per`` is)."""
    distances = offset_distances(offsets, palm_xyz, object_xyz, hover_offset)
    offset, crossed = crossing(distances)
    displacement = max_displacement(offsets, palm_xyz)
    closest = distances.min(axis=0)
    return Failures(
        failure=classify(per, error, displacement, crossed, min_clearance, contact_fails),
        displacement=displacement,
        path_miss=np.where(np.isfinite(closest), closest, np.nan),
        crossing_offset=offset,
        crossed=crossed,
    )
