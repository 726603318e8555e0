"""The paper's events (schemas.events): the boundaries a score depends on."""

from __future__ import annotations

import numpy as np

from schemas import events
from schemas.scene import GRASP_RATIO, LOC_TOLERANCE, PHASES


def test_localized_at_exactly_the_tolerance_and_not_beyond():
    obj = np.array([0.0, 0.2, 0.0])
    at = obj + np.array([LOC_TOLERANCE, 5.0, 0.0])  # height does not count
    beyond = obj + np.array([0.0, 0.0, np.nextafter(LOC_TOLERANCE, 1.0)])
    assert bool(events.localized(at, obj))
    assert not bool(events.localized(beyond, obj))
    assert events.palm_xz_distance(obj + [0.3, 0.0, 0.4], obj) == 0.5


def test_grasp_needs_every_joint_at_the_ratio():
    grasp = np.linspace(0.5, 1.2, 15)
    closed = GRASP_RATIO * grasp
    assert bool(events.grasp_closed(closed, grasp))
    one_short = closed.copy()
    one_short[7] = np.nextafter(one_short[7], 0.0)
    assert not bool(events.grasp_closed(one_short, grasp))


def test_vectorised_calls_agree_with_one_frame_at_a_time():
    rng = np.random.default_rng(3)
    palm, obj = rng.uniform(-1, 1, (50, 3)), rng.uniform(-1, 1, (50, 3))
    joints, grasp = rng.uniform(0, 1.5, (50, 15)), rng.uniform(0, 1.5, (50, 15))
    joints[::3] = grasp[::3]
    many_loc, many_gra = events.localized(palm, obj), events.grasp_closed(joints, grasp)
    assert many_gra.any() and not many_gra.all()
    for k in range(50):
        assert bool(events.localized(palm[k], obj[k])) == many_loc[k]
        assert bool(events.grasp_closed(joints[k], grasp[k])) == many_gra[k]


def test_float32_recordings_decide_as_their_float64_values():
    palm = np.array([[0.3, 0.0, 0.0]], dtype=np.float32)
    obj = np.zeros((1, 3), dtype=np.float32)
    assert events.localized(palm, obj)[0] == (float(np.float32(0.3)) <= LOC_TOLERANCE)


def test_acting_frames_and_budget():
    phase = np.array([PHASES.index(p) for p in ("observe", "observe", "approach", "grasp", "hold")])
    assert events.acting(phase).tolist() == [False, False, True, True, True]
    assert events.acting_budget(40, 10, rollout=False, recorded=17) == 17
    assert events.acting_budget(40, 10, rollout=True, recorded=17) == 36  # ceil(1.2 * 30)
