"""Closed-form motion evaluation: derivatives, curvature, joins, overlays, rolling, bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from generators import segments, tracks
from generators.motion import (
    arc_length,
    curvature,
    evaluate,
    motion_bounds,
    object_angular_velocity,
    object_orientation,
    object_pose,
    qmul,
)
from generators.primitives import clothoid
from schemas.errors import SpecError
from schemas.motion import (
    ArcToken,
    ClothoidToken,
    HarmonicToken,
    LineToken,
    Motion,
    Track,
)
from schemas.objects import OBJECTS

TOKENS = {
    "L": LineToken((0.5, 3.0), 0.3, 1.2, 0.0, 4.0),
    "L-decelerating-through-zero": LineToken((0.5, 3.0), 2.0, 1.0, -0.8, 4.0),
    "A-left": ArcToken((0.0, 4.0), 1.5, 1.2, 0.3, 1, 4.0),
    "A-right": ArcToken((0.0, 4.0), 0.8, 2.5, -2.0, -1, 4.0),
    "H": HarmonicToken((0.0, 4.0), 0.7, 1.0, 0.8, 0.2, 4.0),
    "H-drift": HarmonicToken((0.0, 4.0), 0.7, 1.0, 0.8, 0.2, 4.0, (0.3, -0.1)),
    "C": ClothoidToken(0.5, 4.0, (0.0, 3.0), 0.2, 1.5, 0.4),
    "C-negative-slope": ClothoidToken(-0.3, 4.0, (0.0, 3.0), 2.0, 1.1, 0.9),
    "C-from-straight": ClothoidToken(0.6, 4.0, (0.0, 3.0), -1.0, 1.3, 0.0),
    "C-arc": ClothoidToken(0.0, 4.0, (0.0, 3.0), 0.2, 1.5, 0.7),
    "C-line": ClothoidToken(0.0, 4.0, (0.0, 3.0), 0.2, 1.5, 0.0),
    "C-tiny-slope": ClothoidToken(1e-7, 4.0, (0.0, 3.0), 0.2, 1.5, 0.7),
}

MOTIONS = {
    **{name: Motion.of(tok) for name, tok in TOKENS.items()},
    "LCA": Motion.of(
        LineToken((0.0, 3.0), 0.0, 1.0, 0.0, 1.0), ClothoidToken(0.8, 1.0), ArcToken((0.0, 0.0), 1.0, 1.0, 0.0, 1, 2.0)
    ),
    "overlay": Motion(
        Track((LineToken((-1.0, 3.0), 0.2, 0.8, 0.0, 4.0),)),
        (Track((HarmonicToken((0.0, 0.0), 1.6, 0.4, 1.0, 0.0, 2.0),), 1.0),),
    ),
}

BALL, CAN, MUG, BOX = OBJECTS["tennis_ball"], OBJECTS["soda_can"], OBJECTS["mug"], OBJECTS["cracker_box"]


def finite_differences(m: Motion, t: np.ndarray, h: float = 1e-5):
    plus, minus, mid = evaluate(m, t + h), evaluate(m, t - h), evaluate(m, t)
    velocity = (plus.position - minus.position) / (2 * h)
    acceleration = (plus.velocity - minus.velocity) / (2 * h)
    second = (evaluate(m, t + 1e-3).position - 2 * mid.position + evaluate(m, t - 1e-3).position) / 1e-6
    return velocity, acceleration, second


def interior_times(m: Motion, n: int = 60) -> np.ndarray:
    """Times away from every join (where one-sided derivatives may differ)."""
    t = np.linspace(0.01, m.duration + 0.5, n)
    cuts = [s.t0 for s in segments.segments(m)]
    keep = np.min(np.abs(t[:, None] - np.array(cuts)[None, :]), axis=1) > 2e-3
    return t[keep]


@pytest.mark.parametrize("name", sorted(MOTIONS))
def test_velocity_and_acceleration_match_finite_differences(name):
    m = MOTIONS[name]
    t = interior_times(m)
    sample = evaluate(m, t)
    velocity, acceleration, second = finite_differences(m, t)
    scale = 1.0 + np.abs(sample.acceleration).max()
    assert np.allclose(sample.velocity, velocity, atol=1e-7 * scale)
    assert np.allclose(sample.acceleration, acceleration, atol=1e-6 * scale)
    assert np.allclose(sample.acceleration, second, atol=1e-4 * scale)


def test_line_closed_form_values():
    tok = TOKENS["L-decelerating-through-zero"]
    t = np.array([0.0, 1.25, 3.0])
    s = evaluate(Motion.of(tok), t)
    u = np.array([math.cos(2.0), math.sin(2.0)])
    dist = 1.0 * t - 0.4 * t * t
    assert np.allclose(s.position, np.array(tok.start) + dist[:, None] * u, atol=1e-14)
    assert np.allclose(s.velocity, (1.0 - 0.8 * t)[:, None] * u, atol=1e-14)
    assert np.allclose(s.velocity[1], 0.0, atol=1e-14)


def test_clothoid_fresnel_form_matches_quadrature():
    s = np.linspace(0.0, 6.0, 25)
    for h0, k0, c in [(0.2, 0.7, 0.5), (0.2, -0.7, 0.5), (0.2, 0.7, -0.5), (1.0, 2.0, -0.05), (0.0, 0.0, 0.3), (3.0, -1.5, 2.0)]:
        exact = clothoid.clothoid_integral(h0, k0, c, s)
        assert np.abs(exact - clothoid.clothoid_quadrature(h0, k0, c, s)).max() < 1e-12


def test_clothoid_with_tiny_slope_stays_accurate():
    """Far from its inflection point the Fresnel form loses digits: the quadrature path
    takes over and stays within the slope's effect of the arc with the same start."""
    s = np.linspace(0.0, 6.0, 25)
    tiny = clothoid.clothoid_integral(0.2, 0.7, 1e-9, s)
    arc = clothoid.clothoid_integral(0.2, 0.7, 0.0, s)
    assert np.abs(tiny - arc).max() < 1e-9 * 6.0**3
    assert np.abs(tiny - arc).max() > 0.0


def test_clothoid_matches_arc_and_line_when_slope_is_zero():
    t = np.linspace(0.0, 4.0, 30)
    arc = evaluate(Motion.of(ClothoidToken(0.0, 4.0, (0.0, 3.0), 0.2, 1.5, 0.5)), t)
    # Same circle as an ArcToken: radius 2, centre left of the start heading.
    centre = (0.0 - 2.0 * math.sin(0.2), 3.0 + 2.0 * math.cos(0.2))
    ref = evaluate(Motion.of(ArcToken(centre, 2.0, 0.75, 0.2 - math.pi / 2, 1, 4.0)), t)
    assert np.allclose(arc.position, ref.position, atol=1e-12)
    assert np.allclose(arc.velocity, ref.velocity, atol=1e-12)
    assert np.allclose(arc.acceleration, ref.acceleration, atol=1e-12)
    line = evaluate(Motion.of(ClothoidToken(0.0, 4.0, (0.0, 3.0), 0.2, 1.5, 0.0)), t)
    ref = evaluate(Motion.of(LineToken((0.0, 3.0), 0.2, 1.5, 0.0, 4.0)), t)
    assert np.allclose(line.position, ref.position, atol=1e-12)


def test_curvature_values():
    t = np.linspace(0.0, 3.9, 40)
    assert np.allclose(curvature(Motion.of(TOKENS["L"]), t), 0.0)
    for name in ("A-left", "A-right"):
        tok = TOKENS[name]
        assert np.allclose(curvature(Motion.of(tok), t), 1.0 / tok.radius, rtol=1e-12)
        assert np.allclose(curvature(Motion.of(tok), t, signed=True), tok.turn / tok.radius, rtol=1e-12)
    for name in ("C", "C-negative-slope", "C-from-straight"):
        tok = TOKENS[name]
        kappa = tok.curvature + tok.curvature_slope * tok.speed * t
        assert np.allclose(curvature(Motion.of(tok), t, signed=True), kappa, atol=1e-12)
        assert np.allclose(curvature(Motion.of(tok), t), np.abs(kappa), atol=1e-12)
    # A line slowing to a stop has no heading there: curvature 0, not NaN.
    stop = Motion.of(LineToken((0.0, 3.0), 0.0, 1.0, -1.0, 2.0))
    assert curvature(stop, [1.0])[0] == 0.0


def test_position_continuous_at_joins():
    m = Motion.of(
        LineToken((0.0, 3.0), 0.4, 1.0, 0.3, 1.0),
        ArcToken((5.0, 5.0), 1.2, 2.0, 1.0, -1, 1.5),
        HarmonicToken((9.0, 9.0), 2.0, 0.5, 1.3, 0.7, 1.0, (0.2, 0.1)),
        ClothoidToken(-0.4, 1.0),
        LineToken((-4.0, 0.0), 3.0, 0.5, 0.0, 1.0),
    )
    for join in (1.0, 2.5, 3.5, 4.5):
        around = evaluate(m, [join - 1e-9, join, join + 1e-9]).position
        assert np.abs(around - around[1]).max() < 1e-7
    assert np.allclose(evaluate(m, [0.0]).position, [[0.0, 3.0]])


def _g2_motion() -> tuple[Motion, float, float]:
    """L -> C -> A built so that heading and curvature are continuous too."""
    speed, slope, ct = 1.2, 0.9, 1.0
    length = speed * ct
    kappa = slope * length
    heading = 0.3 + 0.5 * slope * length * length
    radius = 1.0 / kappa
    m = Motion.of(
        LineToken((0.0, 3.0), 0.3, speed, 0.0, 1.0),
        ClothoidToken(slope, ct),
        ArcToken((0.0, 0.0), radius, speed / radius, heading - math.pi / 2, 1, 2.0),
    )
    return m, 1.0, 2.0


def test_line_clothoid_arc_join_is_g2():
    m, j1, j2 = _g2_motion()
    for join in (j1, j2):
        t = np.array([join - 1e-9, join + 1e-9])
        s = evaluate(m, t)
        assert np.abs(s.position[0] - s.position[1]).max() < 1e-8
        assert np.abs(s.velocity[0] - s.velocity[1]).max() < 1e-8
        k = curvature(m, t, signed=True)
        assert abs(k[0] - k[1]) < 1e-7
    assert np.allclose(curvature(m, [1.5], signed=True), 0.9 * 1.2 * 0.5)


def test_clothoid_inherits_heading_speed_and_curvature():
    for prev in (TOKENS["A-right"], TOKENS["H-drift"], TOKENS["C"]):
        m = Motion.of(prev, ClothoidToken(0.25, 1.0, start=(9.0, 9.0), heading=2.0, speed=7.0, curvature=3.0))
        t = np.array([prev.duration - 1e-9, prev.duration])
        s = evaluate(m, t)
        assert np.abs(s.velocity[0] - s.velocity[1]).max() < 1e-7
        k = curvature(m, t, signed=True)
        assert abs(k[0] - k[1]) < 1e-6 * (1 + abs(k[0]))
        assert np.abs(s.position[0] - s.position[1]).max() < 1e-8


def test_clothoid_after_a_stop_stays_still():
    m = Motion.of(LineToken((0.0, 3.0), 0.5, 1.0, -0.5, 2.0), ClothoidToken(0.7, 1.0))
    s = evaluate(m, [2.0, 2.5, 3.0])
    assert np.allclose(s.position, s.position[0])
    assert np.allclose(s.velocity, 0.0)


def test_overlay_adds_its_displacement_on_its_interval():
    base = LineToken((-1.0, 3.0), 0.0, 1.0, 0.0, 5.0)
    sway = HarmonicToken((7.0, 7.0), math.pi / 2, 0.5, 1.0, 0.0, 2.0)
    m = Motion(Track((base,)), (Track((sway,), 1.5),))
    t = np.linspace(0.0, 5.0, 101)
    s, b = evaluate(m, t), evaluate(Motion.of(base), t)
    dz = np.where(t < 1.5, 0.0, 0.5 * np.sin(2 * math.pi * (np.clip(t, 1.5, 3.5) - 1.5)))
    assert np.allclose(s.position[:, 0], b.position[:, 0], atol=1e-14)
    assert np.allclose(s.position[:, 1] - 3.0, dz, atol=1e-12)
    inside = (t >= 1.5) & (t <= 3.5)
    vz = np.where(inside, 0.5 * 2 * math.pi * np.cos(2 * math.pi * (t - 1.5)), 0.0)
    assert np.allclose(s.velocity[:, 1], vz, atol=1e-12)
    assert np.allclose(s.velocity[:, 0], 1.0)


def test_overlays_of_several_tokens_compose():
    sway = Track((LineToken((0.0, 0.0), 1.0, 0.5, 0.0, 1.0), ArcToken((3.0, 3.0), 0.5, 1.0, 0.0, 1, 1.0)), 0.5)
    m = Motion(Track((LineToken((0.0, 3.0), 0.0, 1.0, 0.0, 4.0),)), (sway, sway))
    single = Motion(m.base, (sway,))
    t = np.linspace(0.0, 4.0, 41)
    base = evaluate(Motion(m.base), t).position
    assert np.allclose(evaluate(m, t).position - base, 2 * (evaluate(single, t).position - base), atol=1e-12)


def test_extrapolates_past_the_end():
    tok = LineToken((0.0, 3.0), 0.0, 1.0, 0.5, 1.0)
    s = evaluate(Motion.of(tok), [3.0])
    assert np.allclose(s.position, [[3.0 + 0.25 * 9.0, 3.0]])
    assert np.allclose(s.velocity, [[2.5, 0.0]])


def test_bad_times_raise_spec_error():
    m = MOTIONS["L"]
    with pytest.raises(SpecError, match="-0.5"):
        evaluate(m, [0.0, -0.5])
    with pytest.raises(SpecError, match="nan"):
        evaluate(m, [float("nan")])
    with pytest.raises(SpecError, match="inf"):
        curvature(m, [float("inf")])
    with pytest.raises(SpecError, match="shape"):
        evaluate(m, np.zeros((2, 2)))
    assert evaluate(m, []).position.shape == (0, 2)


def test_arc_length():
    t = np.linspace(0.0, 4.0, 41)
    line = Motion.of(TOKENS["L-decelerating-through-zero"])
    # 1 t - 0.4 t^2 peaks at t = 1.25 (0.625) then comes back.
    expected = np.where(t <= 1.25, t - 0.4 * t * t, 1.25 - (t - 0.4 * t * t))
    assert np.allclose(arc_length(line, t), expected, atol=1e-12)
    arc = TOKENS["A-left"]
    assert np.allclose(arc_length(Motion.of(arc), t), arc.radius * arc.angular_velocity * t)
    for name in ("H", "H-drift", "C", "overlay", "LCA"):
        m = MOTIONS[name]
        step = 1e-5  # midpoint rule: never samples a velocity jump at a join
        v = evaluate(m, (np.arange(400_000) + 0.5) * step).velocity
        cumulative = np.concatenate([[0.0], np.cumsum(np.hypot(v[:, 0], v[:, 1]) * step)])
        assert np.allclose(arc_length(m, t), cumulative[::10_000], atol=1e-6), name


# ----------------------------------------------------------------------------- rolling


def _world_omega(q: np.ndarray, h: float) -> np.ndarray:
    """World angular velocity from central differences of quaternions (x, y, z, w)."""
    dq = (q[:, 2] - q[:, 0]) / (2 * h)
    conj = q[:, 1] * np.array([-1.0, -1.0, -1.0, 1.0])
    return 2.0 * qmul(dq, conj)[:, :3]


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    u, w = q[:, :3], q[:, 3:]
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


@pytest.mark.parametrize("name", sorted(MOTIONS))
@pytest.mark.parametrize("category", [BALL, CAN], ids=lambda c: c.name)
def test_rolling_contact_point_does_not_slip(name, category):
    m, size, h = MOTIONS[name], 0.6, 1e-5
    r = category.rolling_radius(size)
    t = interior_times(m, 40)
    around = np.stack([t - h, t, t + h], axis=1).ravel()
    pose, vel = object_pose(m, category, size, around)
    omega = _world_omega(pose[:, 3:].reshape(-1, 3, 4), h)
    v = vel.reshape(-1, 3, 3)[:, 1]
    contact = v + np.cross(omega, np.array([0.0, -r, 0.0]))
    assert np.abs(contact).max() < 1e-6 * (1.0 + np.abs(v).max())
    closed = object_angular_velocity(m, category, size, t)
    assert np.allclose(closed, omega, atol=1e-4 * (1.0 + np.abs(omega).max()))


@pytest.mark.parametrize("name", sorted(MOTIONS))
def test_lying_cylinder_axis_is_horizontal_and_across_the_path(name):
    m = MOTIONS[name]
    t = interior_times(m, 40)
    pose, vel = object_pose(m, CAN, 0.6, t)
    axis = _rotate(pose[:, 3:], np.tile([1.0, 0.0, 0.0], (len(t), 1)))
    assert np.allclose(axis[:, 1], 0.0, atol=1e-12)
    speed = np.linalg.norm(vel, axis=1)
    moving = speed > 1e-3
    assert np.allclose(np.sum(axis * vel, axis=1)[moving] / speed[moving], 0.0, atol=1e-9)


@pytest.mark.parametrize("name", sorted(MOTIONS))
@pytest.mark.parametrize("category", [BALL, CAN], ids=lambda c: c.name)
def test_quaternions_are_unit_and_continuous(name, category):
    m = MOTIONS[name]
    for t in (np.arange(0, 100) / 20.0, np.linspace(0.0, m.duration, 2001)):
        q = object_orientation(m, category, 0.6, t)
        assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
        dots = np.sum(q[1:] * q[:-1], axis=1)
        assert dots.min() > 0.0
    # Without a kink in the path, consecutive dense samples are close, not just same-signed.
    if name not in ("LCA", "overlay") or category is BALL:
        assert dots.min() > 0.99


def test_lying_cylinder_starts_at_identity_when_travelling_along_z():
    for direction in (math.pi / 2, -math.pi / 2):
        m = Motion.of(LineToken((0.0, 3.0), direction, 1.0, 0.0, 2.0))
        q = object_orientation(m, CAN, 0.6, [0.0, 0.5])
        assert np.allclose(q[0], [0.0, 0.0, 0.0, 1.0])
        # Spinning about its own (body X = world X) axis, by distance / radius.
        angle = 0.5 / CAN.rolling_radius(0.6)
        assert np.allclose(np.abs(q[1]), [abs(math.sin(angle / 2)), 0.0, 0.0, math.cos(angle / 2)])


def test_sphere_on_a_straight_line_turns_about_the_fixed_axis():
    m = Motion.of(LineToken((0.0, 3.0), 0.0, 1.0, 0.0, 2.0))  # along +X
    r = BALL.rolling_radius(0.6)
    q = object_orientation(m, BALL, 0.6, [1.0])[0]
    angle = 1.0 / r  # omega = +Y x +X = -Z
    assert np.allclose(q, [0.0, 0.0, -math.sin(angle / 2), math.cos(angle / 2)])


def test_integrated_orientation_matches_exact_arc():
    """A clothoid with a negligible slope is integrated on the grid; slope 0 is the exact arc."""
    t = np.arange(0, 101) / 20.0
    for speed, kappa in ((1.5, 0.7), (4.0, 2.0)):
        exact = Motion.of(ClothoidToken(0.0, 5.0, (0.0, 3.0), 0.2, speed, kappa))
        grid = Motion.of(ClothoidToken(1e-13, 5.0, (0.0, 3.0), 0.2, speed, kappa))
        assert segments.segments(grid)[0].kind == "general"
        for cat in (BALL, CAN):
            q_exact, q_grid = object_orientation(exact, cat, 0.6, t), object_orientation(grid, cat, 0.6, t)
            assert np.abs(q_exact - q_grid).max() < 1e-7


@pytest.mark.parametrize("name", ["H-drift", "C", "overlay", "LCA"])
def test_orientation_does_not_depend_on_the_other_times_asked(name):
    m = MOTIONS[name]
    t = np.arange(0, 90) / 20.0
    for cat in (BALL, CAN):
        batch = object_orientation(m, cat, 0.6, t)
        alone = np.vstack([object_orientation(m, cat, 0.6, t[i : i + 1]) for i in range(0, 90, 7)])
        assert np.array_equal(batch[::7], alone)
        assert np.array_equal(batch, object_orientation(m, cat, 0.6, t[::-1])[::-1])


def test_non_rolling_objects_keep_identity_and_rest_on_the_table():
    m = MOTIONS["A-left"]
    t = np.arange(0, 40) / 20.0
    for cat in (MUG, BOX):
        pose, vel = object_pose(m, cat, 0.9, t)
        assert np.allclose(pose[:, 3:], [0.0, 0.0, 0.0, 1.0])
        assert np.allclose(pose[:, 1], cat.half_height(0.9))
        assert np.allclose(vel[:, 1], 0.0)
        assert np.allclose(object_angular_velocity(m, cat, 0.9, t), 0.0)
    pose, vel = object_pose(m, "soda_can", 0.6, t)
    s = evaluate(m, t)
    assert np.allclose(pose[:, [0, 2]], s.position)
    assert np.allclose(vel[:, [0, 2]], s.velocity)
    assert np.allclose(pose[:, 1], CAN.rolling_radius(0.6))


def test_object_pose_rejects_bad_size_and_object():
    with pytest.raises(SpecError, match="-1"):
        object_pose(MOTIONS["L"], BALL, -1.0, [0.0])
    with pytest.raises(SpecError, match="nan"):
        object_pose(MOTIONS["L"], BALL, float("nan"), [0.0])
    with pytest.raises(SpecError, match="teapot"):
        object_pose(MOTIONS["L"], "teapot", 0.5, [0.0])


def test_signed_zero_does_not_change_the_output():
    """Equal motions share cache entries; -0.0 must not leak into the results."""
    a = Motion.of(LineToken((0.0, 0.0), 0.0, 1.0, 0.0, 1.0))
    b = Motion.of(LineToken((-0.0, -0.0), -0.0, 1.0, -0.0, 1.0))
    t = np.array([0.0, 0.5])
    tracks.compile_track.cache_clear()
    first = evaluate(b, t).position.tobytes()
    tracks.compile_track.cache_clear()
    evaluate(a, t)
    assert evaluate(b, t).position.tobytes() == first


# ------------------------------------------------------------------------------ bounds


def _dense_bounds(m: Motion, t_end: float) -> np.ndarray:
    p = evaluate(m, np.linspace(0.0, t_end, 200_001)).position
    return np.array([p[:, 0].min(), p[:, 0].max(), p[:, 1].min(), p[:, 1].max()])


@pytest.mark.parametrize("name", sorted(MOTIONS))
@pytest.mark.parametrize("t_end", [0.0, 0.7, 4.0, 5.5])
def test_bounds_match_dense_sampling(name, t_end):
    m = MOTIONS[name]
    bounds = np.array(motion_bounds(m, t_end))
    dense = _dense_bounds(m, t_end)
    # The dense grid's extremes are inside the true ones, by at most |a| dt^2 / 8.
    assert np.all(bounds[[0, 2]] <= dense[[0, 2]] + 1e-12)
    assert np.all(bounds[[1, 3]] >= dense[[1, 3]] - 1e-12)
    assert np.allclose(bounds, dense, atol=1e-8)


def test_bounds_of_a_full_circle_and_bad_t_end():
    m = Motion.of(ArcToken((1.0, 4.0), 2.0, 3.0, 0.1, 1, 5.0))
    assert np.allclose(motion_bounds(m, 4.0), (-1.0, 3.0, 2.0, 6.0))
    with pytest.raises(SpecError, match="-1"):
        motion_bounds(m, -1.0)
    with pytest.raises(SpecError, match="nan"):
        motion_bounds(m, float("nan"))


# -------------------------------------------------------------------------- properties

finite = st.floats(-3.0, 3.0, allow_nan=False)
angle = st.floats(-math.pi, math.pi)
positive = st.floats(0.2, 2.0)
duration = st.floats(0.3, 1.5)

token_strategy = st.one_of(
    st.builds(LineToken, st.tuples(finite, finite), angle, st.floats(0.0, 2.0), st.floats(-1.0, 1.0), duration),
    st.builds(ArcToken, st.tuples(finite, finite), positive, st.floats(0.0, 3.0), angle, st.sampled_from([1, -1]), duration),
    st.builds(
        HarmonicToken, st.tuples(finite, finite), angle, st.floats(0.0, 1.0), st.floats(0.2, 2.0), angle, duration,
        st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)),
    ),
    st.builds(ClothoidToken, st.floats(-1.0, 1.0), duration, st.tuples(finite, finite), angle, st.floats(0.0, 2.0), st.floats(-1.0, 1.0)),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(token_strategy, min_size=1, max_size=4))
def test_property_random_token_sequences(tokens):
    m = Motion.of(*tokens)
    t = interior_times(m, 30)
    sample = evaluate(m, t)
    velocity, acceleration, _ = finite_differences(m, t)
    scale = 1.0 + np.abs(sample.acceleration).max()
    assert np.allclose(sample.velocity, velocity, atol=1e-6 * scale)
    assert np.allclose(sample.acceleration, acceleration, atol=1e-5 * scale)
    joins = np.cumsum([tok.duration for tok in tokens[:-1]])
    for join in joins:
        around = evaluate(m, [join - 1e-10, join]).position
        assert np.abs(around[0] - around[1]).max() < 1e-7
    bounds = np.array(motion_bounds(m, m.duration))
    p = evaluate(m, np.linspace(0.0, m.duration, 2001)).position
    assert bounds[0] <= p[:, 0].min() + 1e-9 and bounds[1] >= p[:, 0].max() - 1e-9
    assert bounds[2] <= p[:, 1].min() + 1e-9 and bounds[3] >= p[:, 1].max() - 1e-9
    for cat in (BALL, CAN):
        q = object_orientation(m, cat, 0.6, np.linspace(0.0, m.duration, 400))
        assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)


def test_token_starts_are_the_exact_prefix_sums_of_durations():
    """Each token starts at the correctly rounded sum of the durations before it (what
    math.fsum of the prefix gives), though the compiler now sums once per token."""
    import math

    rng = np.random.default_rng(11)
    durations = [round(float(d), int(k)) for d, k in zip(rng.uniform(0.011, 0.3, 250), rng.integers(2, 9, 250))]
    track = Track(tuple(LineToken((0.0, 4.0), 0.3, 0.2, 0.0, float(d)) for d in durations), start=0.1)
    compiled = tracks.compile_track(track)
    expected = [0.1 + math.fsum(durations[:i]) for i in range(len(durations))]
    assert compiled.starts.tolist() == expected
