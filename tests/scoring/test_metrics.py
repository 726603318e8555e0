"""Each metric on hand-made trajectories whose answers are worked out by hand."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scoring.metrics import (
    DEFAULT_READING,
    DYANA,
    LENIENT,
    METRIC_NAMES,
    PAPER,
    TOP_BAND,
    Reading,
    aggregate,
    episode_metrics,
    mean_interval,
    path_quality,
    wilson_interval,
)

OPEN = np.zeros(15)
CLOSED = np.ones(15)


def no_hold(per):
    """``per`` with no hold test run (these hand-made hands hold nothing: S_hold is 0)."""
    return dataclasses.replace(per, t_hold=np.full(len(per), -1, dtype=np.int64))


def held(per):
    """``per`` with every grasp that completed counted as held from its closing frame."""
    return dataclasses.replace(per, t_hold=per.t_gra.copy())


def episode(palm, obj=None, joints=None, tips=None):
    """One episode's acting frames: palm (k, 3), object (k, 3) default at the origin."""
    palm = np.asarray(palm, dtype=np.float64).reshape(-1, 3)
    k = len(palm)
    obj = np.zeros((k, 3)) if obj is None else np.asarray(obj, dtype=np.float64).reshape(k, 3)
    joints = np.tile(OPEN, (k, 1)) if joints is None else np.asarray(joints, dtype=np.float64)
    tips = np.full(k, 1.0) if tips is None else np.asarray(tips, dtype=np.float64)
    return palm, obj, joints, tips


def score(*episodes, grasp=None, reading=LENIENT, top=None):
    """episode_metrics over the given episodes, all with grasp_angles CLOSED by default.

    The hand-made answers below were worked out for the ``lenient`` reading (minimum errors,
    zero steps dropped, S_loc in XZ, Q unweighted), Dyana's only rules before readings
    existed; the other readings' differences are tested after them."""
    offsets = np.concatenate([[0], np.cumsum([len(e[0]) for e in episodes])])
    cat = [np.concatenate([e[i] for e in episodes]) if episodes else np.zeros((0, 3)) for i in range(4)]
    grasp = np.tile(CLOSED, (len(episodes), 1)) if grasp is None else np.asarray(grasp)
    return no_hold(episode_metrics(offsets, cat[0], cat[1], cat[2].reshape(-1, 15), cat[3].reshape(-1), grasp,
                                   top_offset=top, reading=reading))


def xs(*values, y=2.0):
    """Palm points along X at height y (Z = 0)."""
    return [[v, y, 0.0] for v in values]


def quality(points, steps="drop"):
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    q_smooth, q_line = path_quality(np.array([0, len(points)]), points, steps)
    return q_smooth[0], q_line[0]


# --- localization -----------------------------------------------------------------


def test_localization_first_frame_within_tolerance_and_min_distance():
    per = score(episode(xs(1.0, 0.5, 0.29, 0.1, 0.2)))
    assert per.t_loc[0] == 2
    assert per.localized[0]
    assert per.e_loc[0] == pytest.approx(0.1)


def test_localization_tolerance_is_inclusive_and_in_the_xz_plane():
    # d = 0.3 exactly; the palm is far above the object (Y is ignored).
    at = score(episode([[0.3, 9.0, 0.0]]))
    assert at.localized[0] and at.e_loc[0] == pytest.approx(0.3)
    beyond = score(episode([[0.18, 0.0, 0.2401]]))
    assert not beyond.localized[0] and beyond.t_loc[0] == -1
    diagonal = score(episode([[1.0, 0.0, 1.0], [0.1, 0.0, -0.2]], obj=[[0, 0, 0], [0.0, 5.0, 0.0]]))
    assert diagonal.t_loc[0] == 1
    assert diagonal.e_loc[0] == pytest.approx(math.hypot(0.1, 0.2))


def test_localization_tracks_a_moving_object():
    palm = xs(0.0, 0.0, 0.0)
    obj = [[2.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.2, 0.0, 0.1]]
    per = score(episode(palm, obj=obj))
    assert per.t_loc[0] == 2
    assert per.e_loc[0] == pytest.approx(math.hypot(0.2, 0.1))


# --- grasp ------------------------------------------------------------------------


def test_grasp_needs_every_joint_at_80_percent_of_ground_truth():
    grasp = np.linspace(0.5, 1.5, 15)
    joints = np.tile(0.85 * grasp, (4, 1))
    joints[0] = 0.0
    joints[1, 7] = 0.79 * grasp[7]  # one joint short: not yet a grasp
    joints[3] = grasp
    per = score(episode(xs(3, 3, 3, 3), joints=joints, tips=[0.9, 0.4, 0.05, 0.2]), grasp=grasp[None])
    assert per.t_gra[0] == 2
    assert per.grasped[0]
    assert per.e_gra[0] == pytest.approx(0.05)


def test_grasp_never_reached():
    joints = np.tile(0.5 * CLOSED, (3, 1))
    per = score(episode(xs(0, 0, 0), joints=joints, tips=[0.3, 0.2, 0.25]))
    assert not per.grasped[0] and per.t_gra[0] == -1
    assert per.e_gra[0] == pytest.approx(0.2)


# --- trajectory quality -----------------------------------------------------------


def test_q_smooth_is_one_over_one_plus_cv_of_steps():
    assert quality(xs(0, 1, 2, 3))[0] == pytest.approx(1.0)
    # steps 1 and 3: mean 2, population std 1 -> 1 / (1 + 1/2)
    assert quality(xs(0, 1, 4))[0] == pytest.approx(2 / 3)


def test_q_smooth_drops_steps_of_at_most_1e_4():
    # the 5e-5 and 9e-5 steps are dropped, leaving steps 1 and 3
    assert quality(xs(0, 1, 1 + 5e-5, 1 + 14e-5, 4 + 14e-5))[0] == pytest.approx(2 / 3)
    # nothing but tiny steps: no step remains -> 1
    assert quality(xs(0, 5e-5, 1e-4))[0] == 1.0


def test_q_line_mean_cosine_to_the_chord():
    # an L: both segments at 45 degrees to the chord
    assert quality([[0, 0, 0], [1, 0, 0], [1, 0, 1]])[1] == pytest.approx(math.sqrt(0.5))
    # overshoot and come back: cosines +1 and -1
    assert quality(xs(0, 2, 1))[1] == pytest.approx(0.0)
    assert quality(xs(0, 1, 2, 3))[1] == pytest.approx(1.0)


def test_q_line_ignores_segments_of_at_most_1e_8():
    points = xs(0, 1, 1 + 5e-9, 2)
    assert quality(points)[1] == pytest.approx(1.0)


def test_q_line_zero_when_the_path_returns_to_its_start():
    assert quality(xs(0, 1, 0))[1] == 0.0
    assert quality(xs(0, 1, 2e-9))[1] == 0.0


def test_paths_of_zero_and_one_point():
    assert quality(np.zeros((0, 3))) == (1.0, 0.0)
    assert quality(xs(5)) == (1.0, 0.0)


def test_paths_of_two_points():
    assert quality(xs(0, 1)) == (1.0, 1.0)
    assert quality(xs(0, 5e-5)) == (1.0, 1.0)  # no step kept for smoothness, still a direction
    assert quality(xs(1, 1)) == (1.0, 0.0)


def test_quality_uses_the_whole_acting_palm_path():
    # palm: 0 -> 1 -> 4 -> 4.8 (localized at x=4.8 with the object at 5), then 0 and 9: the
    # frames after t_loc count too (A.8/A.9's "full palm trajectory")
    palm = xs(0, 1, 4, 4.8, 0, 9)
    obj = [[5.0, 0.0, 0.0]] * 6
    per = score(episode(palm, obj=obj))
    assert per.t_loc[0] == 3
    steps = np.array([1.0, 3.0, 0.8, 4.8, 9.0])
    assert per.q_smooth[0] == pytest.approx(1 / (1 + steps.std() / steps.mean()))
    assert per.q_line[0] == pytest.approx(3 / 5)  # one step of five runs against the chord 0 -> 9


def test_quality_edge_cases_through_episode_metrics():
    obj = [[0.0, 0.0, 0.0]] * 3
    one = score(episode(xs(0.1)))  # one acting frame: N_p = 1
    assert (one.q_smooth[0], one.q_line[0]) == (1.0, 0.0)
    two = score(episode(xs(1, 0.2)))  # N_p = 2
    assert (two.q_smooth[0], two.q_line[0]) == (1.0, 1.0)
    still = score(episode([[0.2, 0, 0], [0.2, 0, 0]]))  # a zero step, dropped; no chord
    assert (still.q_smooth[0], still.q_line[0]) == (1.0, 0.0)
    missed = score(episode(xs(1, 2, 3), obj=obj))  # measured whether or not it localized
    assert not missed.localized[0] and (missed.q_smooth[0], missed.q_line[0]) == (1.0, 1.0)
    none = score(episode(np.zeros((0, 3))))
    assert np.isnan(none.q_smooth[0]) and np.isnan(none.q_line[0])


def test_two_coincident_points_on_the_path():
    # palm stays at x=1 for one frame, then localizes: P = [1, 1, 0.1] -> steps 0 and 0.9
    per = score(episode(xs(1, 1, 0.1)))
    assert per.t_loc[0] == 2
    assert per.q_smooth[0] == 1.0  # the zero step is dropped; one step remains
    assert per.q_line[0] == pytest.approx(1.0)


# --- time score -------------------------------------------------------------------


def test_r_time_uses_the_later_event():
    joints = np.tile(OPEN, (10, 1))
    joints[5:] = CLOSED
    palm = xs(3, 3, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1)
    per = score(episode(palm, joints=joints))
    assert (per.t_loc[0], per.t_gra[0]) == (2, 5)
    assert per.r_time[0] == pytest.approx(1 - 6 / 10)
    # the grasp before the localization: T from t_loc
    joints = np.tile(CLOSED, (10, 1))
    palm = xs(3, 3, 3, 3, 3, 3, 3, 0.1, 0.1, 0.1)
    assert score(episode(palm, joints=joints)).r_time[0] == pytest.approx(1 - 8 / 10)


def test_r_time_zero_when_either_success_is_missing():
    assert score(episode(xs(0.1, 0.1))).r_time[0] == 0.0  # localized, never grasped
    assert score(episode(xs(3, 3), joints=np.tile(CLOSED, (2, 1)))).r_time[0] == 0.0  # grasped only


# --- many episodes ----------------------------------------------------------------


def test_episode_without_acting_frames():
    per = score(episode(np.zeros((0, 3))), episode(xs(0.1)), episode(np.zeros((0, 3))))
    assert list(per.acting_frames) == [0, 1, 0]
    assert list(per.t_loc) == [-1, 0, -1]
    assert np.isnan(per.e_loc[0]) and np.isnan(per.e_gra[2])
    assert per.e_loc[1] == pytest.approx(0.1)
    assert list(per.r_time) == [0.0, 0.0, 0.0]


def naive(palm, obj, joints, tips, grasp, reading=LENIENT, top=0.0):
    """Frame-by-frame reference implementation of the written definitions (any reading)."""
    n = len(palm)
    d = [float(np.hypot(palm[t][0] - obj[t][0], palm[t][2] - obj[t][2])) for t in range(n)]

    def over(t):
        height = palm[t][1] - obj[t][1] - top
        return d[t] <= 0.3 and (reading.s_loc == "xz" or 0.0 <= height <= TOP_BAND)  # 0.35 + 0.3, as computed

    if reading.loc_frame == "any":
        t_loc = next((t for t in range(n) if over(t)), -1)
    else:  # endpoint: over the object at the last frame, held since t_loc
        t_loc = -1
        for t in reversed(range(n)):
            if not over(t):
                break
            t_loc = t
    t_gra = next((t for t in range(n) if all(joints[t][j] >= 0.8 * grasp[j] for j in range(15))), -1)
    q_smooth = q_line = float("nan")
    if n:
        p = [np.asarray(palm[t], dtype=float) for t in range(n)]
        segs = [p[k + 1] - p[k] for k in range(len(p) - 1)]
        chord = p[-1] - p[0]
        cn = float(np.linalg.norm(chord))
        if reading.steps == "drop":
            steps = [float(np.linalg.norm(s)) for s in segs if np.linalg.norm(s) > 1e-4]
            q_smooth = 1.0 / (1.0 + float(np.std(steps)) / float(np.mean(steps))) if steps else 1.0
            cos = [float(s @ chord) / (float(np.linalg.norm(s)) * cn) for s in segs
                   if np.linalg.norm(s) > 1e-8] if cn >= 1e-8 else []  # no chord: no direction to compare with
            q_line = float(np.mean(cos)) if cos else 0.0
        else:
            steps = [float(np.linalg.norm(s)) for s in segs]
            mean = float(np.mean(steps)) if steps else 0.0
            q_smooth = 1.0 / (1.0 + float(np.std(steps)) / mean) if mean > 0 else 0.0
            cos = [float(s @ chord) / (float(np.linalg.norm(s)) * cn) if np.linalg.norm(s) > 1e-8 else 0.0
                   for s in segs] if cn >= 1e-8 else []  # no chord: Q_line 0
            q_line = sum(cos) / len(cos) if cos else 0.0
    r_time = 1 - (max(t_loc, t_gra) + 1) / n if t_loc >= 0 and t_gra >= 0 else 0.0
    if not n:
        e_loc = e_gra = float("nan")
    else:
        e_loc = min(d) if reading.e_loc == "minimum" else d[-1]
        e_gra = float(min(tips)) if reading.e_gra == "minimum" else float(tips[t_gra if t_gra >= 0 else -1])
    return t_loc, t_gra, e_loc, e_gra, q_smooth, q_line, r_time


coord = st.floats(-1.0, 1.0, allow_nan=False).map(lambda v: round(v, 2))


@st.composite
def episodes(draw):
    k = draw(st.integers(0, 8))
    palm = [[draw(coord), draw(coord), draw(coord)] for _ in range(k)]
    obj = [[draw(coord), 0.0, draw(coord)] for _ in range(k)]
    grasp = np.full(15, 1.0)
    joints = [np.full(15, draw(st.sampled_from([0.0, 0.5, 0.8, 1.0]))) for _ in range(k)]
    tips = [abs(draw(coord)) for _ in range(k)]
    return palm, obj, joints, tips, grasp


@settings(max_examples=60, deadline=None, derandomize=True)  # the same examples on every run and host
@given(st.lists(episodes(), min_size=1, max_size=6), st.sampled_from([LENIENT, PAPER, DYANA]))
def test_vectorised_matches_the_frame_by_frame_definitions(eps, reading):
    arrays = [
        episode(np.asarray(p).reshape(-1, 3), obj=np.asarray(o).reshape(-1, 3),
                joints=np.asarray(j).reshape(-1, 15), tips=np.asarray(t).reshape(-1))
        for p, o, j, t, _ in eps
    ]
    per = score(*arrays, grasp=np.stack([g for *_, g in eps]), reading=reading)
    for i, (p, o, j, t, g) in enumerate(eps):
        expected = naive(p, o, j, t, g, reading)
        got = (per.t_loc[i], per.t_gra[i], per.e_loc[i], per.e_gra[i], per.q_smooth[i], per.q_line[i], per.r_time[i])
        assert got[:2] == expected[:2]
        np.testing.assert_allclose(got[2:], expected[2:], rtol=1e-9, atol=1e-12, equal_nan=True)


def test_bad_offsets_are_rejected():
    with pytest.raises(ValueError, match="offsets"):
        episode_metrics(np.array([0, 2]), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 15)), np.zeros(3),
                        np.zeros((1, 15)))


# --- aggregates -------------------------------------------------------------------


def test_aggregate_means_and_percentages():
    hit = episode(xs(1, 0.2, 0.2), joints=np.tile(CLOSED, (3, 1)), tips=[0.5, 0.1, 0.3])  # t_loc 1, t_gra 0
    miss = episode(xs(2, 1), tips=[0.7, 0.3])
    per = score(hit, miss)
    summary = aggregate(per, np.zeros(2, dtype=bool))
    assert summary.episodes == 2 and summary.errors == 0
    assert summary.metrics["S_loc"] == pytest.approx(50.0)
    assert summary.metrics["S_gra"] == pytest.approx(50.0)
    assert summary.metrics["E_loc"] == pytest.approx((0.2 + 1.0) / 2)
    assert summary.metrics["E_gra"] == pytest.approx((0.1 + 0.3) / 2)
    assert summary.metrics["Q_smooth"] == pytest.approx(1.0)  # only the successful trajectory counts
    assert summary.metrics["Q_line"] == pytest.approx(1.0)
    assert summary.averaged_over == {"E_loc": 2, "E_gra": 2, "Q_smooth": 1, "Q_line": 1, "R_time": 2}
    assert summary.metrics["R_time"] == pytest.approx((1 - 2 / 3 + 0.0) / 2)
    assert tuple(summary.metrics) == METRIC_NAMES
    low, high = summary.intervals["S_loc"]
    assert low < 50.0 < high


def test_no_localized_episode_gives_null_quality():
    per = score(episode(xs(2, 3)), episode(xs(4)))
    summary = aggregate(per, np.zeros(2, dtype=bool))
    assert summary.metrics["S_loc"] == 0.0
    assert summary.metrics["Q_smooth"] is None and summary.metrics["Q_line"] is None
    assert summary.intervals["Q_smooth"] is None


def test_error_episodes_are_failures_everywhere_but_keep_their_distances():
    good = episode(xs(1, 0.1, 0.1), joints=np.tile(CLOSED, (3, 1)), tips=[0.4, 0.2, 0.3])
    per = score(good, good)
    summary = aggregate(per, np.array([False, True]))
    assert summary.errors == 1
    assert summary.metrics["S_loc"] == pytest.approx(50.0)
    assert summary.metrics["S_gra"] == pytest.approx(50.0)
    assert per.r_time[0] == pytest.approx(1 / 3)
    assert summary.metrics["R_time"] == pytest.approx(per.r_time[0] / 2)
    assert summary.metrics["E_loc"] == pytest.approx(0.1)
    assert summary.metrics["Q_smooth"] == pytest.approx(1.0)
    # an error episode that recorded no frame is left out of the error means only
    per = score(good, episode(np.zeros((0, 3))))
    summary = aggregate(per, np.array([False, True]))
    assert summary.metrics["E_gra"] == pytest.approx(0.2)
    assert summary.metrics["S_loc"] == pytest.approx(50.0)


def test_aggregate_selection():
    per = score(episode(xs(0.1)), episode(xs(5)), episode(xs(0.2)))
    summary = aggregate(per, np.zeros(3, dtype=bool), select=np.array([True, True, False]))
    assert summary.episodes == 2 and summary.metrics["S_loc"] == pytest.approx(50.0)
    empty = aggregate(per, np.zeros(3, dtype=bool), select=np.zeros(3, dtype=bool))
    assert empty.episodes == 0
    assert all(value is None for value in empty.metrics.values())
    assert all(value is None for value in empty.intervals.values())


def test_wilson_interval_known_values():
    low, high = wilson_interval(5, 10)
    assert (low, high) == (pytest.approx(0.2366, abs=1e-4), pytest.approx(0.7634, abs=1e-4))
    low, high = wilson_interval(0, 10)
    assert low == 0.0 and high == pytest.approx(0.2775, abs=1e-4)
    low, high = wilson_interval(1000, 1000)
    assert high == pytest.approx(1.0) and low == pytest.approx(0.99617, abs=1e-5)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError):
        wilson_interval(3, 2)


def test_mean_interval():
    assert mean_interval(np.array([1.0])) is None
    low, high = mean_interval(np.array([1.0, 3.0]))
    half = 1.959963984540054 * math.sqrt(2) / math.sqrt(2)
    assert (low, high) == (pytest.approx(2 - half), pytest.approx(2 + half))


@pytest.mark.parametrize("n", [1, 7, 180, 1000])
def test_wilson_interval_reaches_the_extremes_exactly(n):
    assert wilson_interval(n, n)[1] == 1.0
    assert wilson_interval(0, n)[0] == 0.0


# --- the contact-grounded grasp (paper A.8) ------------------------------------------


def _one_episode(palm_x, tips, closed_mask):
    """Acting frames of one episode: palm XZ offset per frame, fingertip distance, joints closed or open."""
    m = len(palm_x)
    grasp = np.full((1, 15), 1.0)
    joints = np.where(np.asarray(closed_mask)[:, None], 1.0, 0.0) * np.ones((m, 15))
    palm = np.column_stack([palm_x, np.full(m, 0.5), np.zeros(m)])
    return no_hold(episode_metrics(np.array([0, m]), palm, np.zeros((m, 3)), joints, np.asarray(tips, float), grasp))


def test_contact_grasp_needs_the_fist_over_the_object_and_touching_at_the_same_frame():
    from schemas.scene import GRASP_CONTACT_TOLERANCE as EPS

    blind_fist = _one_episode([2.0, 2.0, 2.0], [1.5, 1.5, 1.5], [False, True, True])
    assert blind_fist.grasped[0] and not blind_fist.contact_grasped[0]
    hovering_fist = _one_episode([0.1, 0.1], [EPS * 1.5, EPS * 1.5], [True, True])
    assert hovering_fist.grasped[0] and not hovering_fist.contact_grasped[0]
    apart_in_time = _one_episode([0.1, 2.0, 0.1], [0.05, 0.05, 0.05], [False, True, False])
    assert apart_in_time.grasped[0] and apart_in_time.localized[0] and not apart_in_time.contact_grasped[0]
    held = _one_episode([1.0, 0.1, 0.1], [0.5, EPS, 0.02], [False, True, True])
    assert held.contact_grasped[0] and held.t_contact[0] == 1


def test_the_ground_truth_grasps_with_contact_and_a_blind_fist_does_not():
    """Ground truth 100 on S_grasp_contact; a policy that lowers the palm where it is and closes
    the fist scores on the joint-only S_gra but 0 on the contact grasp. (Lowered to 1.5, not
    to the table: the hand is a body, and fingers curling into the table stop there.)"""
    from generators.recipe import spec_for
    from pipeline import episode
    from pipeline.loop.wrappers import loop_env
    from scoring.io import from_recordings
    from scoring.report import score_run

    specs = [spec_for("test-1k", i) for i in range(6)]
    truth = score_run(from_recordings("gt", "test-1k", specs, [episode(s) for s in specs])).overall
    assert truth.metrics["S_grasp_contact"] == 100.0 and truth.metrics["S_gra"] == 100.0

    env = loop_env(resolution=32)
    recordings = []
    for spec in specs:
        obs, _ = env.reset(options={"spec": spec})
        done = False
        while not done:
            fist = np.concatenate([[obs["palm_pose"][0], 1.5, obs["palm_pose"][2]], np.full(15, 1.6)]).astype(np.float32)
            obs, _, terminated, truncated, _ = env.step(fist)
            done = terminated or truncated
        recordings.append(env.recording()[0])
    blind = score_run(from_recordings("fist", "test-1k", specs, recordings, policy="fist")).overall
    assert blind.metrics["S_gra"] > 0 and blind.metrics["S_loc"] == 0
    assert blind.metrics["S_grasp_contact"] == 0.0


# --- the dyana (the default) and paper readings: where they differ from the lenient one -----


def test_dyana_reading_is_the_default():
    assert DEFAULT_READING == "dyana" and (DYANA.s_loc, DYANA.quality) == ("top", "weighted")
    assert (PAPER.s_loc, PAPER.quality) == ("xz", "successful")  # A.5's XZ test; "for successful trajectories"
    per = no_hold(episode_metrics(np.array([0, 2]), np.array(xs(1.0, 0.2, y=0.3)), np.zeros((2, 3)),
                                  np.zeros((2, 15)), np.array([0.1, 0.5]), np.ones((1, 15))))
    assert per.e_loc[0] == pytest.approx(0.2) and per.e_gra[0] == pytest.approx(0.5)  # the last frame's


def test_e_loc_at_the_endpoint_and_e_gra_at_completion():
    joints = np.tile(OPEN, (4, 1))
    joints[2:] = CLOSED
    palm = episode(xs(1.0, 0.1, 0.5, 2.0, y=0.3), joints=joints, tips=[0.05, 0.2, 0.4, 0.9])
    lenient, paper, dyana = score(palm), score(palm, reading=PAPER), score(palm, reading=DYANA)
    assert (dyana.e_loc[0], dyana.e_gra[0]) == (paper.e_loc[0], paper.e_gra[0])
    assert (lenient.e_loc[0], lenient.e_gra[0]) == (pytest.approx(0.1), pytest.approx(0.05))
    assert paper.e_loc[0] == pytest.approx(2.0)  # where the palm ended
    assert paper.e_gra[0] == pytest.approx(0.4)  # at t_gra = 2, the grasp's completion
    never = score(episode(xs(1.0, 0.1, y=0.3), tips=[0.05, 0.7]), reading=PAPER)
    assert never.e_gra[0] == pytest.approx(0.7)  # no completion: the last frame


def test_paper_reading_keeps_zero_steps():
    # jump once, then hold: the lenient reading sees one step (1.0, 1.0)
    points = xs(0, 3, 3, 3, 3, 3)
    assert quality(points) == (1.0, 1.0)
    steps = np.array([3.0, 0, 0, 0, 0])
    q_smooth, q_line = quality(points, "keep")
    assert q_smooth == pytest.approx(1 / (1 + steps.std() / steps.mean()))
    assert q_line == pytest.approx(1 / 5)  # one step along the chord, four without direction
    assert quality(xs(2, 2, 2), "keep") == (0.0, 0.0)  # never moved: no motion to call smooth
    assert quality(xs(2), "keep") == (0.0, 0.0)
    assert quality(xs(0, 1, 2, 3), "keep") == (1.0, 1.0)


def test_s_loc_needs_the_palm_above_the_top_surface():
    obj = [[0.0, 1.0, 0.0]] * 4
    top = np.array([0.5])  # the object's top at y = 1.5
    inside = episode(xs(1, 0.1, 0.1, 0.1, y=1.2), obj=obj)  # over it in XZ, but below its top
    assert score(inside, top=top).localized[0] and score(inside, top=top, reading=PAPER).localized[0]
    assert not score(inside, top=top, reading=DYANA).localized[0]
    hover = episode([[1, 1.85, 0], [0.1, 2.3, 0], [0.1, 1.85, 0], [0.1, 1.5, 0]], obj=obj)
    per = score(hover, top=top, reading=DYANA)
    assert per.t_loc[0] == 2  # 0.8 above the top is too high; 0.35 (the ground truth's hover) is in
    edge = episode([[0.1, 1.5 + TOP_BAND, 0]], obj=obj[:1])
    assert score(edge, top=top, reading=DYANA).localized[0]  # both ends of the band are inclusive


def test_contact_grasp_follows_the_reading_s_loc():
    obj = [[0.0, 1.0, 0.0]] * 2
    fist_inside = episode(xs(0.1, 0.1, y=1.0), obj=obj, joints=np.tile(CLOSED, (2, 1)), tips=[0.05, 0.05])
    assert score(fist_inside, top=np.array([0.5])).contact_grasped[0]
    assert score(fist_inside, top=np.array([0.5]), reading=PAPER).contact_grasped[0]
    assert not score(fist_inside, top=np.array([0.5]), reading=DYANA).contact_grasped[0]


def test_reading_rejects_unknown_rules():
    with pytest.raises(ValueError, match="e_loc"):
        Reading("odd", e_loc="median")
    with pytest.raises(ValueError, match="steps"):
        path_quality(np.array([0, 1]), np.zeros((1, 3)), "skip")


# --- quality weighted by success (the dyana reading) ------------------------------------


def test_blind_play_cannot_win_quality_under_the_default_reading():
    """A straight line at constant speed that passes over the object and closes the hand away
    from it (blind play) is a perfect path: the paper's unweighted Q gives it 1.00 over its one
    successful trajectory; weighted by the headline success (S_hold) it scores 0, below a
    wobbly approach that grasps and holds the object (counted as held here: the hold test
    needs pybullet and a real hand, tests/scoring/test_hold.py runs it)."""
    from scoring.registry import SUCCESS, metric_named, success

    assert metric_named(SUCCESS).headline  # the success that weights Q is the headline's
    line = episode(xs(-2, -1, 0, 1, 2), joints=np.tile(CLOSED, (5, 1)), tips=[1.0] * 5)
    miss = episode(xs(3, 4, 5, 6), tips=[1.0] * 4)
    wobbly = episode(xs(2, 1.5, 1.4, 0.6, 0.1, y=0.3), joints=np.tile(CLOSED, (5, 1)), tips=[0.9, 0.8, 0.6, 0.3, 0.05])
    summaries = {}
    for reading in (PAPER, DYANA):
        blind = aggregate(score(line, miss, miss, reading=reading), np.zeros(3, bool))
        model = aggregate(held(score(wobbly, reading=reading)), np.zeros(1, bool))
        summaries[reading.name] = blind, model
    blind, model = summaries["paper"]
    assert (blind.metrics["Q_smooth"], blind.metrics["Q_line"]) == (1.0, 1.0) and blind.averaged_over["Q_line"] == 1
    assert blind.metrics["Q_smooth"] > model.metrics["Q_smooth"]
    blind, model = summaries["dyana"]
    assert (blind.metrics["Q_smooth"], blind.metrics["Q_line"]) == (0.0, 0.0) and blind.averaged_over["Q_line"] == 3
    assert not success(score(wobbly, reading=DYANA), np.ones(1, bool))[0]  # grasped, but not held
    per = held(score(wobbly, reading=DYANA))
    assert success(per, np.ones(1, bool))[0]
    assert per.q_smooth[0] > 0.0 and model.metrics["Q_smooth"] == pytest.approx(per.q_smooth[0])
    assert model.metrics["Q_line"] == pytest.approx(1.0)


def test_a_palm_that_sweeps_past_the_object_is_localized_only_in_the_papers_reading():
    """The dyana reading judges localization where the hand ends (the palm held over the object
    from t_loc to the last frame); the paper's, at any frame. A hand that passes over the object
    and goes on is localized only in the paper's."""
    top = 0.5  # the object's top over its centre; the palm at 0.8 is 0.3 over it
    sweep = [[-1.0, 0.8, 0.0], [0.0, 0.8, 0.0], [1.0, 0.8, 0.0], [2.0, 0.8, 0.0]]
    arrive = [[-1.0, 0.8, 0.0], [0.1, 0.8, 0.0], [1.0, 0.8, 0.0], [0.2, 0.8, 0.0], [0.0, 0.8, 0.0]]
    eps = [episode(np.asarray(p), obj=np.zeros((len(p), 3))) for p in (sweep, arrive)]
    dyana = score(*eps, reading=DYANA, top=np.full(2, top))
    paper = score(*eps, reading=PAPER, top=np.full(2, top))
    assert dyana.t_loc.tolist() == [-1, 3]  # the arrival: over from frame 3 to the end (frame 1 was a pass)
    assert paper.t_loc.tolist() == [1, 1]
