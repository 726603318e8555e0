"""Obstacle-aware grasping (paper A.11): paths around a box, the ground-truth hand's lift and
clearance, the slices and byte-identical builds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from generators.clearance import hand_clearance, object_clearance
from generators.recipe import slice_specs, slice_summary, spec_for
from generators.tracks import evaluate
from pipeline import episode
from schemas.obstacles import OBSTACLE_MARGIN, Obstacle
from schemas.scene import PALM_REST
from schemas.spec import EpisodeSpec
from schemas.versions import FPS


@pytest.fixture(scope="module")
def specs() -> list[EpisodeSpec]:
    return [spec_for("test-complex", i) for i in (1, 4, 7)] + list(slice_specs("obstacle-slow", 3))


def test_the_object_goes_around_the_first_obstacle_with_continuous_velocity(specs):
    for spec in specs:
        kinds = spec.motion.token_types
        assert kinds in ("LAL", "LA") and spec.motion_type == "obstacle"
        arc = spec.motion.base.tokens[1]
        assert arc.centre == spec.obstacles[0].centre
        t0 = spec.motion.base.tokens[0].duration
        before, after = evaluate(spec.motion, [t0 - 1e-7]), evaluate(spec.motion, [t0 + 1e-7])
        np.testing.assert_allclose(before.velocity, after.velocity, atol=1e-5)
        centre = np.array(arc.centre)
        distance = np.linalg.norm(evaluate(spec.motion, [t0 + 0.5 * arc.duration]).position[0] - centre)
        assert distance == pytest.approx(arc.radius, abs=1e-9)


def test_ground_truth_keeps_the_margin_from_every_obstacle_and_intercepts_on_time(specs):
    for spec in specs:
        frames = episode(spec)
        hand = hand_clearance(frames.palm_pose.astype(np.float64), frames.joint_angles.astype(np.float64),
                              spec.hand, spec.obstacles)
        assert hand.min() >= OBSTACLE_MARGIN - 1e-6
        target = object_clearance(spec.object, spec.object_size, frames.object_pose.astype(np.float64), spec.obstacles)
        assert target.min() >= OBSTACLE_MARGIN
        i = spec.intercept_frame
        assert frames.palm_distance[i] <= 1e-4 < frames.palm_distance[i - 1]


def test_an_obstacle_on_the_way_lifts_the_approach_and_only_as_much_as_needed():
    spec = spec_for("linear-medium", 3)
    plain = episode(spec)
    a, i = spec.observe_frames, spec.intercept_frame
    middle = plain.palm_pose[(a + i) // 2]
    wall = Obstacle("book", (float(middle[0]), float(middle[2])), (0.75, 0.5, 0.3))
    lifted = episode(dataclasses.replace(spec, obstacles=(wall,)))
    assert (lifted.palm_pose[a + 1 : i, 1] > plain.palm_pose[a + 1 : i, 1]).all()
    np.testing.assert_array_equal(lifted.palm_pose[: a + 1], plain.palm_pose[: a + 1])
    np.testing.assert_array_equal(lifted.palm_pose[i:], plain.palm_pose[i:])
    clear = hand_clearance(lifted.palm_pose.astype(np.float64), lifted.joint_angles.astype(np.float64), spec.hand,
                           (wall,))
    assert OBSTACLE_MARGIN - 1e-6 <= clear.min() < OBSTACLE_MARGIN + 0.5
    unaffected = Obstacle("brick", (3.0, -0.5), (0.3, 0.2, 0.3))
    assert PALM_REST[2] < 1.0
    np.testing.assert_array_equal(episode(dataclasses.replace(spec, obstacles=(unaffected,))).palm_pose,
                                  plain.palm_pose)


def test_obstacle_slices_and_stats():
    summary = slice_summary("obstacle-fast", 6)
    specs = list(slice_specs("obstacle-fast", 6))
    assert summary["motion_types"]["obstacle"]["episodes"] == 6
    assert summary["total_frames"] == sum(s.num_frames for s in specs)
    assert all(1 <= len(s.obstacles) <= 2 for s in specs)
    assert all(s.num_frames / FPS <= s.motion.duration + 1e-9 for s in specs)
    assert EpisodeSpec.from_json(specs[0].to_json()) == specs[0]


def test_test_complex_interleaves_the_three_settings():
    specs = list(slice_specs("test-complex", 9))
    assert [s.motion_type for s in specs] == ["projectile", "obstacle", "irregular"] * 3
    assert [s.intercept_setting for s in specs[::3]] == ["fast", "medium", "slow"]
    summary = slice_summary("test-complex")
    assert {k: v["episodes"] for k, v in summary["motion_types"].items()} == {
        "projectile": 100, "obstacle": 100, "irregular": 100
    }
