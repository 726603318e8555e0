"""Obstacle contact as a scored event: the collision rate, and contact failing an episode."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.stages.episode import episode, obstacle_clearance
from schemas.errors import SpecError
from schemas.obstacles import Obstacle
from scoring.io import from_recordings
from scoring.report import format_table, markdown, report_dict, score_run


def _run(contact: str):
    """Three ground-truth episodes: one without obstacles, one whose lifted approach clears
    its box, and one whose hand took the straight (unlifted) path through the same box."""
    plain = episode_spec(1)
    clear = episode_spec(0)
    base = episode(clear)
    middle = base.palm_pose[(clear.observe_frames + clear.intercept_frame) // 2]
    wall = Obstacle("crate", (float(middle[0]), float(middle[2])), (0.6, 0.6, 0.3))
    cleared = dataclasses.replace(clear, obstacles=(wall,))
    hit = dataclasses.replace(clear, episode_index=2, obstacles=(wall,))
    through = dataclasses.replace(base, obstacle_clearance=obstacle_clearance(hit, base.palm_pose, base.joint_angles))
    specs = [plain, cleared, hit]
    recordings = [episode(plain), episode(cleared), through]
    return score_run(from_recordings("gt", "linear-medium", specs, recordings), "gt", contact), through


def episode_spec(index: int):
    from generators.recipe import spec_for

    return spec_for("linear-medium", 3 + index)


def test_a_hand_through_an_obstacle_is_a_collision_and_the_rate_counts_episodes_with_obstacles():
    report, through = _run("report")
    assert through.obstacle_clearance.min() <= 0.0
    s = report.overall
    assert (s.obstacle_episodes, s.collisions) == (2, 1)
    assert s.collision_rate == pytest.approx(50.0)
    assert s.metrics["S_loc"] == pytest.approx(100.0)
    out = report_dict(report)
    assert out["obstacles"] == {"episodes": 2, "collisions": 1, "collision_rate": 50.0, "contact": "report"}
    assert "Obstacles:" in format_table([report]) and "### Obstacles" in markdown([report])
    per = report.data.min_clearance
    assert np.isinf(per[0]) and per[1] > 0.0 >= per[2]


def test_by_default_the_colliding_episode_is_a_failure_not_an_error():
    for report in (_run("fail")[0], score_run(_run("report")[0].data, "gt")):
        s = report.overall
        assert s.metrics["S_loc"] == pytest.approx(200.0 / 3.0)
        assert s.metrics["S_grasp_contact"] == pytest.approx(200.0 / 3.0)
        assert s.errors == 0 and s.collisions == 1
        assert report_dict(report)["obstacles"]["contact"] == "fail"
        assert report.failures.failure.tolist() == ["success", "success", "obstacle_contact"]


def test_runs_without_obstacles_report_no_obstacle_section():
    spec = episode_spec(0)
    report = score_run(from_recordings("gt", "linear-medium", [spec], [episode(spec)]), "gt")
    assert spec.obstacles == ()
    assert report.data.min_clearance is None and "obstacles" not in report_dict(report)
    assert "Obstacles:" not in format_table([report])
    with pytest.raises(SpecError, match="obstacle_contact"):
        score_run(report.data, "gt", "ignore")
