"""The paper's metrics (section 4.2, A.5) as pure, vectorised functions.

Every function works on the *acting* frames of many episodes concatenated in
episode order, delimited by ``offsets`` (``n + 1`` non-decreasing integers,
``offsets[0] == 0``): episode ``i`` owns rows ``offsets[i]:offsets[i + 1]``.
Reductions use ``numpy.ufunc.reduceat`` and ``numpy.bincount``, never a Python
loop over frames or episodes. The definitions are written out in docs/reference/metrics.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from schemas import events
from schemas.errors import SpecError
from schemas.names import shorten
from schemas.obstacles import CONTACT_CLEARANCE
from schemas.scene import LOC_TOLERANCE, PALM_HOVER
from scoring.registry import table_metrics

#: Steps no longer than this are dropped before measuring smoothness (the ``lenient`` reading).
STEP_MIN = 1e-4
#: Segments (and chords) no longer than this have no direction.
SEGMENT_MIN = 1e-8
#: The built-in metrics (:mod:`scoring.registry`, as registered at import; code that must
#: see metrics registered later calls :func:`scoring.registry.table_metrics`): Dyana's
#: headline ``S_hold`` (a grasp that holds the object, :mod:`scoring.hold`), then the seven of
#: the paper's Table 3 in its order and ``S_grasp_contact`` (the contact-grounded grasp,
#: :func:`schemas.events.contact_grasp`).
METRIC_NAMES = tuple(m.name for m in table_metrics())
#: The headline success, first in every table: the one a blind policy cannot win.
HEADLINE = next(m.name for m in table_metrics() if m.headline)
#: The success rates among them (percent, with Wilson intervals).
SUCCESS_RATE_NAMES = tuple(m.name for m in table_metrics() if m.is_rate)
#: Metrics where lower is better (the rest: higher is better).
LOWER_IS_BETTER = tuple(m.name for m in table_metrics() if m.lower_is_better)
#: Two-sided 95% normal quantile.
Z95 = 1.959963984540054


#: The choices of :class:`Reading` (the first of each is the ``dyana`` reading's).
E_LOC_RULES = ("endpoint", "minimum")
E_GRA_RULES = ("completion", "minimum")
STEP_RULES = ("keep", "drop")
S_LOC_RULES = ("top", "xz")
LOC_FRAME_RULES = ("endpoint", "any")
QUALITY_RULES = ("weighted", "successful")


@dataclass(frozen=True)
class Reading:
    """How the paper's ambiguous metrics are read (docs/reference/metrics.md, "Readings").

    ``e_loc``: the palm distance at the last acting frame (``endpoint``) or its minimum
    over the acting frames (``minimum``); ``e_gra``: the closest fingertip's distance at
    grasp completion, the last acting frame if none (``completion``), or its minimum
    (``minimum``); ``steps``: Q_smooth/Q_line over every step of the path (``keep``) or
    without the steps of at most :data:`STEP_MIN` (``drop``); ``s_loc``: localization
    also needs the palm above the object's top by at most :data:`TOP_BAND` (``top``), or
    the XZ distance only (``xz``); ``quality``: Q_smooth/Q_line of every episode, times its
    success (:data:`scoring.registry.SUCCESS`; ``weighted``, 0 for a failure), or
    unweighted over the successful trajectories only (``successful``: localized and grasped);
    ``loc_frame``: where localization is judged: at the last acting frame, the palm held
    over the object from ``t_loc`` to the end (``endpoint``), or at any acting frame
    (``any``, A.5's "exists"). Q is always measured over the whole acting palm trajectory.
    """

    name: str
    e_loc: str = "endpoint"
    e_gra: str = "completion"
    steps: str = "keep"
    s_loc: str = "top"
    quality: str = "weighted"
    loc_frame: str = "endpoint"

    def __post_init__(self) -> None:
        for rule, choices in (("e_loc", E_LOC_RULES), ("e_gra", E_GRA_RULES), ("steps", STEP_RULES),
                              ("s_loc", S_LOC_RULES), ("quality", QUALITY_RULES), ("loc_frame", LOC_FRAME_RULES)):
            if getattr(self, rule) not in choices:
                raise ValueError(f"Reading.{rule} must be one of {choices}, got {getattr(self, rule)!r}")


#: Dyana's reading, the default: the paper's rules where its text is clear, the height band
#: for "above", localization judged where the hand ends (a palm that sweeps past the object
#: is not localized: benchmarks/results/blind_adversaries.md), and trajectory quality
#: weighted by success (as SPL weights path length).
DYANA = Reading("dyana")
#: The paper's text only: A.5's XZ localization test at any frame, Q unweighted over the
#: successful trajectories ("for successful trajectories"), the captions' endpoint errors.
PAPER = Reading("paper", s_loc="xz", quality="successful", loc_frame="any")
#: The paper's text read the other way where it is ambiguous ("shortest" distances; zero
#: steps dropped): kinder to a policy that games it.
LENIENT = Reading("lenient", e_loc="minimum", e_gra="minimum", steps="drop", s_loc="xz", quality="successful",
                  loc_frame="any")
READINGS = {r.name: r for r in (DYANA, PAPER, LENIENT)}
DEFAULT_READING = DYANA.name
#: The ``top`` rule: the palm centre's height above the object's top surface lies in
#: [0, TOP_BAND]: above it, and within the localization tolerance of the ground truth's
#: hover height (the ground truth hovers at PALM_HOVER = 0.35 over the top; with the
#: opposed hand of 5.x, 0.45-0.5 over boxes and 0.13-0.48 over lying cylinders, all
#: within the band's 0.65).
TOP_BAND = PALM_HOVER + LOC_TOLERANCE


def reading_named(name: str) -> Reading:
    """The registered reading ``name``; SpecError (a ValueError) naming ``reading`` and the known ones."""
    if not isinstance(name, str) or name not in READINGS:
        raise SpecError(f"reading must be one of {sorted(READINGS)}, got {shorten(repr(name))}")
    return READINGS[name]


def above_top(palm_xyz: np.ndarray, object_xyz: np.ndarray, top_offset: np.ndarray) -> np.ndarray:
    """Whether the palm centre is above the object's top (centre + ``top_offset``) by at most
    :data:`TOP_BAND` (per frame)."""
    height = np.asarray(palm_xyz, dtype=np.float64)[..., 1] - np.asarray(object_xyz, dtype=np.float64)[..., 1]
    height = height - np.asarray(top_offset, dtype=np.float64)
    return (height >= 0.0) & (height <= TOP_BAND)


def _check_offsets(offsets: np.ndarray, rows: int) -> np.ndarray:
    offsets = np.asarray(offsets, dtype=np.int64)
    if offsets.ndim != 1 or len(offsets) < 1 or offsets[0] != 0 or offsets[-1] != rows:
        raise ValueError(f"offsets must run from 0 to {rows}, got {offsets[:3]}...{offsets[-3:]}")
    if np.any(np.diff(offsets) < 0):
        raise ValueError("offsets must be non-decreasing")
    return offsets


def _segment_min(values: np.ndarray, offsets: np.ndarray, empty: float) -> np.ndarray:
    """Minimum of ``values`` over each segment; ``empty`` for segments without rows."""
    counts = np.diff(offsets)
    out = np.full(len(counts), empty, dtype=values.dtype if values.dtype.kind == "f" else np.int64)
    nonempty = counts > 0
    if nonempty.any():
        out[nonempty] = np.minimum.reduceat(values, offsets[:-1][nonempty])
    return out


def _segment_max(values: np.ndarray, offsets: np.ndarray, empty: int) -> np.ndarray:
    """Per-episode maximum of integer ``values`` (``empty`` for an episode without rows)."""
    out = np.full(len(offsets) - 1, empty, dtype=np.int64)
    nonempty = np.diff(offsets) > 0
    if nonempty.any():
        out[nonempty] = np.maximum.reduceat(values, offsets[:-1][nonempty])
    return out


def _at_rows(values: np.ndarray, rows: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``values[rows]`` where ``valid`` (one row per episode), NaN elsewhere."""
    out = np.full(len(rows), np.nan)
    out[valid] = values[rows[valid]]
    return out


def path_quality(offsets: np.ndarray, points: np.ndarray, steps: str = "keep") -> tuple[np.ndarray, np.ndarray]:
    """``(Q_smooth, Q_line)`` of each path (points ``offsets[i]:offsets[i + 1]``, shape (m, 3)).

    ``steps="keep"`` (the paper's formula): every step ``|P[k+1] - P[k]|`` counts;
    ``Q_smooth = 1 / (1 + std / mean)`` (population std), 0 when the mean step is 0 (no
    step, or the palm never moved: no motion to call smooth); ``Q_line`` is the sum over
    the steps of the cosine between the step and the chord ``P[-1] - P[0]``, divided by
    the number of steps, a step of at most :data:`SEGMENT_MIN` adding 0 (it has no
    direction); 0 when the chord is shorter than that or there is no step.

    ``steps="drop"`` (the ``lenient`` reading): only steps longer than :data:`STEP_MIN`
    count for Q_smooth (1 if none remains), and Q_line is the mean over the segments
    longer than :data:`SEGMENT_MIN` only (0 if none, or the chord is that short). A path
    of 0 or 1 point gets (1, 0), one of 2 points (1, 1), or (1, 0) if they coincide.
    """
    if steps not in STEP_RULES:
        raise ValueError(f"steps must be one of {STEP_RULES}, got {steps!r}")
    drop = steps == "drop"
    points = np.asarray(points, dtype=np.float64)
    offsets = _check_offsets(offsets, len(points))
    n = len(offsets) - 1
    counts = np.diff(offsets)
    owner = np.repeat(np.arange(n), counts)

    same = owner[1:] == owner[:-1]
    moves = (points[1:] - points[:-1])[same]
    step_owner = owner[1:][same]
    length = np.linalg.norm(moves, axis=1)

    kept = length > STEP_MIN if drop else np.ones(len(length), dtype=bool)
    kept_owner = step_owner[kept]
    kept_count = np.bincount(kept_owner, minlength=n)
    safe_count = np.maximum(kept_count, 1)
    mean = np.bincount(kept_owner, weights=length[kept], minlength=n) / safe_count
    spread = length[kept] - mean[kept_owner]
    std = np.sqrt(np.bincount(kept_owner, weights=spread * spread, minlength=n) / safe_count)
    q_smooth = np.ones(n) if drop else np.zeros(n)
    has_steps = (kept_count > 0) & (mean > 0)
    q_smooth[has_steps] = 1.0 / (1.0 + std[has_steps] / mean[has_steps])

    chord = np.zeros((n, 3))
    nonempty = counts > 0
    chord[nonempty] = points[offsets[1:][nonempty] - 1] - points[offsets[:-1][nonempty]]
    chord_length = np.linalg.norm(chord, axis=1)
    directed = chord_length >= SEGMENT_MIN
    seg = (length > SEGMENT_MIN) & directed[step_owner]
    seg_owner = step_owner[seg]
    cosine = np.einsum("ij,ij->i", moves[seg], chord[seg_owner]) / (length[seg] * chord_length[seg_owner])
    # keep: every step counts in the denominator (a directionless one adds 0); drop: only segments
    seg_count = np.bincount(seg_owner, minlength=n) if drop else np.bincount(step_owner, minlength=n) * directed
    q_line = np.zeros(n)
    has_segments = seg_count > 0
    q_line[has_segments] = np.bincount(seg_owner, weights=cosine, minlength=n)[has_segments] / seg_count[has_segments]
    return q_smooth, q_line


@dataclass(frozen=True)
class EpisodeMetrics:
    """Per-episode facts read off the acting frames (arrays of length ``n``).

    ``t_loc``/``t_gra`` count from the first acting frame and are -1 when the event
    never happens; ``e_loc``/``e_gra``/``q_smooth``/``q_line`` are NaN for an episode
    without acting frames (Q over the whole acting palm trajectory); ``r_time`` is 0
    unless both events happened; ``quality`` is the reading's rule for Q
    (:data:`QUALITY_RULES`); ``t_hold`` needs pybullet, so :func:`scoring.hold.run_metrics`
    adds it. Statuses are not applied here (see :func:`aggregate`).
    """

    acting_frames: np.ndarray
    t_loc: np.ndarray
    t_gra: np.ndarray
    e_loc: np.ndarray
    e_gra: np.ndarray
    q_smooth: np.ndarray
    q_line: np.ndarray
    r_time: np.ndarray
    t_contact: np.ndarray
    quality: str = DYANA.quality
    #: (n,) ``t_gra`` where the hold test held from there, else -1 (:mod:`scoring.hold`);
    #: None until it has run (:func:`scoring.hold.run_metrics`).
    t_hold: np.ndarray | None = None

    @property
    def contact_grasped(self) -> np.ndarray:
        """The contact-grounded grasp (:func:`schemas.events.contact_grasp`) happened."""
        return self.t_contact >= 0

    @property
    def localized(self) -> np.ndarray:
        return self.t_loc >= 0

    @property
    def grasped(self) -> np.ndarray:
        return self.t_gra >= 0

    def __len__(self) -> int:
        return len(self.t_loc)


def episode_metrics(
    offsets: np.ndarray,
    palm_xyz: np.ndarray,
    object_xyz: np.ndarray,
    joint_angles: np.ndarray,
    fingertip_distance: np.ndarray,
    grasp_angles: np.ndarray,
    acting_budget: np.ndarray | None = None,
    hover_offset: np.ndarray | None = None,
    top_offset: np.ndarray | None = None,
    reading: Reading = DYANA,
) -> EpisodeMetrics:
    """Per-episode metrics from the acting frames of ``n`` episodes.

    ``palm_xyz``/``object_xyz`` (m, 3), ``joint_angles`` (m, 15), ``fingertip_distance``
    (m,) are the acting frames in order; ``grasp_angles`` (n, 15) the episodes' ground
    truth. Distances are computed in float64 from the recorded values.
    ``acting_budget`` (n,) is R_time's N, the acting frames the episode could last
    (rollouts stop at grasp completion, so their recorded count would always give 0);
    by default the recorded acting frames. ``hover_offset`` (n,) makes localization 3D
    for flying objects (:func:`schemas.events.palm_distance`; NaN: in XZ, the default).
    ``top_offset`` (n,) is the height of each object's top above its centre, for the
    ``top`` localization rule (default 0: the top at the centre); ``reading`` chooses
    the rules where the paper is ambiguous (:class:`Reading`).
    """
    if not isinstance(reading, Reading):
        raise ValueError(f"reading must be a scoring.metrics.Reading, got {type(reading).__name__}")
    palm = np.asarray(palm_xyz, dtype=np.float64)
    obj = np.asarray(object_xyz, dtype=np.float64)
    joints = np.asarray(joint_angles, dtype=np.float64)
    tips = np.asarray(fingertip_distance, dtype=np.float64)
    grasp = np.asarray(grasp_angles, dtype=np.float64)
    m = len(palm)
    offsets = _check_offsets(offsets, m)
    n = len(offsets) - 1
    if obj.shape != (m, 3) or palm.shape != (m, 3):
        raise ValueError(f"palm_xyz and object_xyz must have shape ({m}, 3), got {palm.shape} and {obj.shape}")
    if joints.shape[0] != m or tips.shape != (m,):
        raise ValueError(f"joint_angles and fingertip_distance must have {m} rows")
    if grasp.shape != (n, joints.shape[1]):
        raise ValueError(f"grasp_angles must have shape ({n}, {joints.shape[1]}), got {grasp.shape}")

    counts = np.diff(offsets)
    owner = np.repeat(np.arange(n), counts)
    local = np.arange(m, dtype=np.int64) - offsets[:-1][owner]
    never = np.iinfo(np.int64).max

    airborne = np.zeros(n, dtype=bool)
    if hover_offset is None:
        d_xz = events.palm_xz_distance(palm, obj)
    else:
        offset = np.asarray(hover_offset, dtype=np.float64)
        if offset.shape != (n,):
            raise ValueError(f"hover_offset must have shape ({n},), got {offset.shape}")
        d_xz = events.palm_distance(palm, obj, offset[owner])
        airborne = ~np.isnan(offset)
    top = np.zeros(n) if top_offset is None else np.asarray(top_offset, dtype=np.float64)
    if top.shape != (n,):
        raise ValueError(f"top_offset must have shape ({n},), got {top.shape}")
    over = events.within_tolerance(d_xz)
    if reading.s_loc == "top":  # a flying object's 3D distance to its hover point already bounds the height
        over = over & (airborne[owner] | above_top(palm, obj, top[owner]))
    if reading.loc_frame == "endpoint":  # the first frame of the run of over-object frames that ends the episode
        last_miss = _segment_max(np.where(over, -1, local), offsets, -1)
        ends_over = np.zeros(n, dtype=bool)
        ends_over[counts > 0] = over[(offsets[1:] - 1)[counts > 0]]
        first_loc = np.where(ends_over, last_miss + 1, never)
    else:
        first_loc = _segment_min(np.where(over, local, never), offsets, never)
    closed = events.grasp_closed(joints, grasp[owner])
    first_gra = _segment_min(np.where(closed, local, never), offsets, never)
    t_loc = np.where(first_loc == never, -1, first_loc)
    t_gra = np.where(first_gra == never, -1, first_gra)
    last = offsets[1:] - 1
    has_frames = counts > 0
    if reading.e_loc == "minimum":
        e_loc = _segment_min(d_xz, offsets, np.nan)
    else:  # the endpoint: the last acting frame
        e_loc = _at_rows(d_xz, last, has_frames)
    if reading.e_gra == "minimum":
        e_gra = _segment_min(tips, offsets, np.nan)
    else:  # at completion (t_gra), else where the episode ended
        e_gra = _at_rows(tips, np.where(t_gra >= 0, offsets[:-1] + t_gra, last), has_frames)
    held = events.contact_grasp(over, closed, tips)
    first_contact = _segment_min(np.where(held, local, never), offsets, never)
    t_contact = np.where(first_contact == never, -1, first_contact)

    q_smooth, q_line = path_quality(offsets, palm, reading.steps)  # the whole acting trajectory
    q_smooth = np.where(has_frames, q_smooth, np.nan)
    q_line = np.where(has_frames, q_line, np.nan)

    localized = t_loc >= 0
    both = localized & (t_gra >= 0)
    done = np.maximum(t_loc, t_gra) + 1
    budget = counts if acting_budget is None else np.asarray(acting_budget, dtype=np.int64)
    if budget.shape != (n,):
        raise ValueError(f"acting_budget must have shape ({n},), got {budget.shape}")
    r_time = np.where(both, 1.0 - done / np.maximum(budget, 1), 0.0)
    return EpisodeMetrics(counts, t_loc, t_gra, e_loc, e_gra, q_smooth, q_line, r_time, t_contact, reading.quality)


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion, as fractions in [0, 1].

    With ``n == 0`` nothing is known and the interval is (0, 1).
    """
    if n < 0 or successes < 0 or successes > n:
        raise ValueError(f"need 0 <= successes <= n, got successes={successes}, n={n}")
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    z2 = z * z
    denominator = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denominator
    half = z * math.sqrt(p * (1.0 - p) / n + z2 / (4.0 * n * n)) / denominator
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == n else min(1.0, centre + half)
    return low, high


def mean_interval(values: np.ndarray, z: float = Z95) -> tuple[float, float] | None:
    """Normal-approximation interval of a mean (sample std); None with fewer than 2 values."""
    values = np.asarray(values, dtype=np.float64)
    if len(values) < 2:
        return None
    mean = float(values.mean())
    half = z * float(values.std(ddof=1)) / math.sqrt(len(values))
    return mean - half, mean + half


@dataclass(frozen=True)
class Summary:
    """The registered metrics (:func:`scoring.registry.metric_names`) over a set of episodes,
    with counts and 95% intervals.

    ``metrics`` maps each metric's name to a float or None (success rates in
    percent); ``intervals`` maps each to ``(low, high)`` or None, success rates by
    Wilson (percent), the means by the normal approximation; ``averaged_over`` maps each
    mean to the number of episodes it averages (its coverage).
    """

    episodes: int
    errors: int
    localized: int
    grasped: int
    metrics: dict[str, float | None]
    intervals: dict[str, tuple[float, float] | None]
    #: Episodes with obstacles, and those in which the hand touched one (obstacle contact).
    obstacle_episodes: int = 0
    collisions: int = 0
    averaged_over: dict[str, int] = field(default_factory=dict)

    @property
    def collision_rate(self) -> float | None:
        """Percent of the episodes with obstacles in which the hand touched one."""
        return 100.0 * self.collisions / self.obstacle_episodes if self.obstacle_episodes else None


def _mean(values: np.ndarray) -> float | None:
    return float(values.mean()) if len(values) else None


def failed(error: np.ndarray, min_clearance: np.ndarray | None = None, contact_fails: bool = True) -> np.ndarray:
    """(n,) the episodes scored as failures whatever their frames show: those in ``error``
    (a policy error or time-out) and, with ``contact_fails``, those whose hand touched an
    obstacle (``min_clearance`` at or below :data:`schemas.obstacles.CONTACT_CLEARANCE`).
    The summaries and the per-episode rows both apply it."""
    error = np.asarray(error, dtype=bool)
    if min_clearance is None or not contact_fails:
        return error
    return error | (np.asarray(min_clearance, dtype=np.float64) <= CONTACT_CLEARANCE)


def aggregate(
    per: EpisodeMetrics,
    error: np.ndarray,
    select: np.ndarray | None = None,
    z: float = Z95,
    min_clearance: np.ndarray | None = None,
    contact_fails: bool = True,
) -> Summary:
    """Summarise episodes (all, or those where ``select`` is true).

    ``min_clearance`` (n,) is each episode's smallest hand-obstacle clearance over its acting
    frames (+inf without obstacles): at or below :data:`schemas.obstacles.CONTACT_CLEARANCE`
    the hand touched an obstacle, counted in ``collisions``; with ``contact_fails`` such an
    episode also counts as a failure, like an error (:func:`failed`).

    An episode whose status is ``error`` counts as a failure in every success rate
    (and so scores ``R_time`` 0, and Q_smooth/Q_line 0 or nothing, by the reading)
    whatever its recorded frames show; its recorded acting frames still count in ``E_loc``
    and ``E_gra``. Episodes without acting frames are left out of those two means.
    Each mean averages the episodes its metric counts (``averaged_over``; None if none).
    """
    error = np.asarray(error, dtype=bool)
    if error.shape != (len(per),):
        raise ValueError(f"error must have shape ({len(per)},), got {error.shape}")
    keep = np.ones(len(per), dtype=bool) if select is None else np.asarray(select, dtype=bool)
    errors = int((error & keep).sum())
    obstacle_episodes = collisions = 0
    if min_clearance is not None:
        clearance = np.asarray(min_clearance, dtype=np.float64)
        with_obstacles = np.isfinite(clearance) & keep
        collided = with_obstacles & (clearance <= CONTACT_CLEARANCE)
        obstacle_episodes, collisions = int(with_obstacles.sum()), int(collided.sum())
    n = int(keep.sum())
    ok = ~failed(error, min_clearance, contact_fails)
    n_loc, n_gra = int((per.localized & ok & keep).sum()), int((per.grasped & ok & keep).sum())
    metrics: dict[str, float | None] = {}
    intervals: dict[str, tuple[float, float] | None] = {}
    averaged_over: dict[str, int] = {}
    for metric in table_metrics():
        if metric.is_rate:
            k = int((metric.success(per, ok) & keep).sum())
            metrics[metric.name] = 100.0 * k / n if n else None
            low, high = wilson_interval(k, n, z)
            intervals[metric.name] = (100.0 * low, 100.0 * high) if n else None
        else:
            assert metric.value is not None and metric.counted is not None
            counted = metric.counted(per, ok) & keep
            values = metric.value(per, ok)[counted]
            metrics[metric.name] = _mean(values)
            intervals[metric.name] = mean_interval(values, z)
            averaged_over[metric.name] = int(counted.sum())
    return Summary(n, errors, n_loc, n_gra, metrics, intervals, obstacle_episodes, collisions, averaged_over)
