"""Object shapes through their registry (schemas.shapes): a toy shape registered here works
wherever shapes are dispatched on, and an unknown shape name is a clear SpecError."""

from __future__ import annotations

import math

import numpy as np
import pytest

from generators import scene
from generators.bullet import p
from generators.clearance import object_clearances
from generators.contact import signed_distance, signed_distance_local
from generators.rolling import object_pose
from generators.visibility import object_surface_points
from pipeline.policies import silhouette
from schemas.errors import SpecError
from schemas.motion import LineToken, Motion, Track
from schemas.objects import OBJECTS, ObjectCategory, object_category
from schemas.obstacles import Obstacle
from schemas.shapes import ObjectShape, Solid, VisualPart, register, registered, shape_named, unregister
from schemas.shapes.base import BOX_SIGNS

_LINE = Motion(Track((LineToken(start=(0.0, 4.0), direction=0.0, speed=1.0, acceleration=0.0, duration=3.0),)))


class Crate(ObjectShape):
    """A toy shape: a cube given by one half edge, ``dims`` (half,)."""

    dims = ("half",)

    def half_height(self, dims, lying):
        return dims[0]

    def roll_mode(self, lying):
        return None

    def signed_distance(self, points, dims, axis):
        q = np.abs(points) - dims[0]
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)

    def hull_points(self, dims, lying):
        return BOX_SIGNS * dims[0]

    def reach(self, dims, lying, hypot=math.hypot):
        return float(hypot(dims[0], dims[0]))

    def silhouette_points(self, dims, lying, heading):
        return BOX_SIGNS * dims[0]

    def visual_parts(self, dims, lying, rgba, mark):
        return [VisualPart("box", (dims[0],) * 3, rgba)]

    def solid(self, dims, lying):
        return Solid("box", (dims[0],) * 3)


@pytest.fixture
def crate(monkeypatch):
    """The toy shape registered as ``crate`` and a category ``toy_crate`` of it, shaped as
    toy_cube (a 0.3 half edge), so every result can be compared with toy_cube's."""
    register("crate")(Crate)
    try:
        category = ObjectCategory("toy_crate", "crate", (0.30,), False, (0.5, 0.5, 0.5, 1.0))
        monkeypatch.setitem(OBJECTS, "toy_crate", category)
        monkeypatch.setitem(scene.MARKING_RGBA, "toy_crate", (0.0, 0.0, 0.0, 1.0))
        yield category
    finally:
        unregister("crate")


def test_a_toy_shape_works_wherever_shapes_are_dispatched_on(crate):
    cube = OBJECTS["toy_cube"]
    assert "crate" in registered() and object_category("toy_crate").geometry is shape_named("crate")
    assert crate.nominal_size == cube.nominal_size and crate.size_range == cube.size_range
    size = 0.75
    assert crate.half_height(size) == cube.half_height(size)
    rng = np.random.default_rng(3)
    points = rng.uniform(-1.0, 1.0, size=(4, 6, 3))
    poses = np.concatenate([rng.uniform(-1.0, 1.0, size=(4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))], axis=1)
    assert np.allclose(signed_distance(points, "toy_crate", size, poses), signed_distance(points, "toy_cube", size, poses))
    assert np.allclose(object_surface_points("toy_crate", size, poses), object_surface_points("toy_cube", size, poses))
    obstacles = [Obstacle("brick", (1.0, 4.0), (0.5, 0.3, 0.2), 0.3)]
    near = poses + [0.5, 0.0, 4.0, 0.0, 0.0, 0.0, 0.0]
    assert np.allclose(object_clearances("toy_crate", size, near, obstacles), object_clearances("toy_cube", size, near, obstacles))
    assert np.allclose(silhouette.surface_points(crate, size, 0.0), silhouette.surface_points(cube, size, 0.0))
    assert silhouette.headings(crate) == (0.0,)
    times = np.linspace(0.0, 0.5, 5)
    assert np.allclose(object_pose(_LINE, crate, size, times)[0], object_pose(_LINE, cube, size, times)[0])
    parts = scene.object_parts("toy_crate", size)
    assert parts[0].shape == p.GEOM_BOX and parts[0].dims == pytest.approx(cube.scaled_dims(size))
    client = p.connect(p.DIRECT)
    try:
        body = scene.build_object(client, "toy_crate", size)
        assert p.getVisualShapeData(body, physicsClientId=client)[0][2] == p.GEOM_BOX
    finally:
        p.disconnect(client)


def test_a_toy_shape_that_cannot_roll_is_refused_as_a_rolling_category(crate):
    rolling = ObjectCategory("rolling_crate", "crate", (0.30,), True, (0.5, 0.5, 0.5, 1.0))
    with pytest.raises(SpecError, match="crate cannot roll"):
        object_pose(_LINE, rolling, 0.6, np.zeros(1))


def test_unknown_shape_names_are_one_clear_spec_error():
    with pytest.raises(SpecError, match=r"unknown shape 'cone' \(expected one of \['box', 'cylinder', 'sphere'\]\)"):
        shape_named("cone")
    with pytest.raises(SpecError, match=r"object 'dunce_cap': unknown shape 'cone' \(expected one of"):
        ObjectCategory("dunce_cap", "cone", (1.0,), False, (1.0, 1.0, 1.0, 1.0))
    with pytest.raises(SpecError, match="unknown shape 'cone'"):
        signed_distance_local(np.zeros(3), "cone", (1.0,))
    with pytest.raises(SpecError, match="bad dims"):
        ObjectCategory("flat_ball", "sphere", (1.0, 2.0), False, (1.0, 1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="already registered"):
        register("box")(Crate)
    with pytest.raises(SpecError, match="unknown solid 'cone'"):
        VisualPart("cone", (1.0,), (1.0, 1.0, 1.0, 1.0))
