"""Projectile interception (paper A.11): the closed-form flight and bounces, the 3D
interception of the ground truth, 3D localization, the slices and byte-identical builds."""

from __future__ import annotations

import numpy as np
import pytest

from generators.ballistics import REST_SPEED, elevation
from generators.motion import object_pose
from generators.projectile import MIN_AIR
from generators.recipe import slice_specs, slice_summary, spec_for
from pipeline import episode
from schemas.errors import SpecError
from schemas.events import localized, palm_distance, spec_hover_offset
from schemas.motion import LineToken, Motion, ProjectileToken
from schemas.scene import LOC_TOLERANCE

G = 98.1


def throw(**changes) -> Motion:
    values = {"start": (0.0, 4.0), "velocity": (1.0, 6.0, 0.5), "duration": 3.0, "height": 1.0, "restitution": 0.6}
    values.update(changes)
    return Motion.of(ProjectileToken(**values))


def test_flight_follows_the_closed_form_until_it_lands():
    motion = throw()
    land = (6.0 + np.sqrt(36.0 + 2.0 * G * 1.0)) / G
    t = np.linspace(0.0, land * 0.999, 50)
    e = elevation(motion, t)
    np.testing.assert_allclose(e.height, 1.0 + 6.0 * t - 0.5 * G * t * t, atol=1e-12)
    np.testing.assert_allclose(e.velocity, 6.0 - G * t, atol=1e-12)
    assert (e.acceleration == -G).all()
    h = 1e-6
    mid = t[1:-1]
    numeric = (elevation(motion, mid + h).height - elevation(motion, mid - h).height) / (2 * h)
    np.testing.assert_allclose(numeric, elevation(motion, mid).velocity, atol=1e-5)


def test_each_bounce_returns_restitution_times_the_impact_speed_and_the_ball_comes_to_rest():
    motion = throw(restitution=0.6)
    land = (6.0 + np.sqrt(36.0 + 2.0 * G)) / G
    impact = 6.0 - G * land
    after = elevation(motion, [land + 1e-9])
    assert after.velocity[0] == pytest.approx(-0.6 * impact, rel=1e-6)
    t = np.linspace(0.0, 3.0, 3001)
    e = elevation(motion, t)
    assert (e.height >= 0.0).all()
    apexes = [e.height[k] for k in range(1, len(t) - 1) if e.velocity[k - 1] > 0 >= e.velocity[k]]
    assert all(b < a for a, b in zip(apexes, apexes[1:])) and len(apexes) >= 3
    assert e.height[-1] == 0.0 and e.velocity[-1] == 0.0 and abs(e.velocity[t > 2.5]).max() < REST_SPEED


def test_without_restitution_the_object_lands_and_slides_on():
    motion = throw(restitution=0.0)
    e = elevation(motion, [2.0])
    assert e.height[0] == 0.0 and e.velocity[0] == 0.0
    pose, velocity = object_pose(motion, "tennis_ball", 0.67, [0.0, 2.0])
    assert pose[1, 1] == pytest.approx(0.335) and velocity[1, 1] == 0.0
    np.testing.assert_allclose(pose[1, [0, 2]], [2.0, 5.0])


def test_a_planar_token_after_a_flight_needs_the_object_on_the_table():
    line = LineToken((0.0, 0.0), 0.0, 1.0, 0.0, 1.0)
    flying = Motion.of(ProjectileToken((0.0, 4.0), (0.0, 5.0, 0.0), 0.2, height=1.0), line)
    with pytest.raises(SpecError, match=r"still .* in the air"):
        elevation(flying, [0.5])
    landed = Motion.of(ProjectileToken((0.0, 4.0), (0.0, 0.0, 0.0), 1.0, height=1.0), line)
    assert elevation(landed, [1.5]).height[0] == 0.0


def test_the_object_pose_rises_with_the_flight():
    motion = throw()
    pose, velocity = object_pose(motion, "baseball", 0.74, [0.1])
    e = elevation(motion, [0.1])
    assert pose[0, 1] == pytest.approx(0.37 + e.height[0])
    assert velocity[0, 1] == pytest.approx(e.velocity[0])


def test_localization_of_a_flying_object_is_3d():
    obj = np.array([[0.0, 2.0, 4.0]])
    offset = 0.5
    over = np.array([[0.0, 2.5, 4.0]])
    under = np.array([[0.0, 0.5, 4.0]])
    assert localized(over, obj, offset)[0] and not localized(under, obj, offset)[0]
    assert localized(under, obj)[0]  # in XZ alone a palm under the object would count
    assert palm_distance(under, obj, offset)[0] == pytest.approx(2.0)
    assert palm_distance(under, obj, float("nan"))[0] == 0.0


def test_ground_truth_catches_every_ball_in_the_air_at_the_intercept_frame():
    specs = list(slice_specs("test-complex", 9))[0::3]  # its projectile episodes, one per setting
    assert [s.motion_type for s in specs] == ["projectile"] * 3
    assert sorted(s.intercept_setting for s in specs) == ["fast", "medium", "slow"]
    for spec in specs + [spec_for("projectile-slow", 7)]:
        frames = episode(spec)
        i = spec.intercept_frame
        lift = elevation(spec.motion, [i / 20]).height[0]
        assert lift >= MIN_AIR
        assert frames.palm_distance[i] <= 1e-4
        assert frames.palm_distance[i - 1] > frames.palm_distance[i]
        assert frames.palm_distance[i - 1] <= LOC_TOLERANCE or frames.palm_distance[i + 1] <= LOC_TOLERANCE
        assert np.isfinite(spec_hover_offset(spec))
        assert frames.object_pose[i, 1] > 0.3  # in the air


def test_projectile_slices_and_stats():
    summary = slice_summary("projectile-fast", 6)
    specs = list(slice_specs("projectile-fast", 6))
    assert summary["motion_types"]["projectile"]["episodes"] == 6
    assert summary["total_frames"] == sum(s.num_frames for s in specs)
    assert {s.object for s in specs} <= {"tennis_ball", "baseball", "orange"}
    assert all(s.motion.airborne and s.motion_type == "projectile" for s in specs)
