"""Analytic hand-object distances: known cases and pybullet's closest points."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

from generators.contact import (
    fingertip_distance,
    quaternion_to_matrix,
    signed_distance,
    signed_distance_local,
    to_local,
)
from schemas.events import palm_xz_distance
from schemas.objects import OBJECTS

PROBE_RADIUS = 0.01


def _random_quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_quaternion_matches_pybullet():
    for q in _random_quaternions(np.random.default_rng(0), 20):
        expected = np.array(p.getMatrixFromQuaternion(q.tolist())).reshape(3, 3)
        np.testing.assert_allclose(quaternion_to_matrix(q), expected, atol=1e-12)


def test_known_distances():
    assert signed_distance_local(np.array([0.0, 0.0, 0.0]), "sphere", (0.5,)) == pytest.approx(-0.5)
    assert signed_distance_local(np.array([0.0, 2.0, 0.0]), "sphere", (0.5,)) == pytest.approx(1.5)
    cyl = (0.5, 2.0)  # radius, length along local Z
    assert signed_distance_local(np.array([1.5, 0.0, 0.3]), "cylinder", cyl) == pytest.approx(1.0)
    assert signed_distance_local(np.array([0.0, 0.2, 3.0]), "cylinder", cyl) == pytest.approx(2.0)
    assert signed_distance_local(np.array([0.0, 0.0, 0.0]), "cylinder", cyl) == pytest.approx(-0.5)
    assert signed_distance_local(np.array([0.0, 0.0, 0.9]), "cylinder", cyl) == pytest.approx(-0.1)
    assert signed_distance_local(np.array([0.5 + 3.0, 0.0, 1.0 + 4.0]), "cylinder", cyl) == pytest.approx(5.0)
    box = (1.0, 0.5, 0.25)
    assert signed_distance_local(np.array([2.0, 0.0, 0.0]), "box", box) == pytest.approx(1.0)
    assert signed_distance_local(np.array([0.0, 0.0, 0.0]), "box", box) == pytest.approx(-0.25)
    assert signed_distance_local(np.array([4.0, 4.5, 0.0]), "box", box) == pytest.approx(5.0)


def test_cylinder_axes_follow_the_scene_convention():
    """At identity an upright cylinder runs along Y and a lying one along X."""
    identity = np.array([[1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]])
    pts = np.array([[[1.0, 2.0 + 0.9, 3.0], [1.0 + 0.9, 2.0, 3.0], [1.0, 2.0, 3.0 + 0.9]]])
    radius, length = OBJECTS["mug"].dims
    upright = signed_distance(pts, "mug", OBJECTS["mug"].nominal_size, identity)[0]
    np.testing.assert_allclose(upright, [0.9 - length / 2, 0.9 - radius, 0.9 - radius])
    radius, length = OBJECTS["soda_can"].dims
    lying = signed_distance(pts, "soda_can", OBJECTS["soda_can"].nominal_size, identity)[0]
    np.testing.assert_allclose(lying, [0.9 - radius, 0.9 - length / 2, 0.9 - radius])


def test_orientation_is_applied():
    """A lying cylinder yawed by 90 degrees about Y runs along Z."""
    half = np.sin(np.pi / 4)
    pose = np.array([[1.0, 2.0, 3.0, 0.0, half, 0.0, half]])
    pts = np.array([[[1.0 + 0.9, 2.0, 3.0], [1.0, 2.0, 3.0 + 0.9]]])
    radius, length = OBJECTS["soda_can"].dims
    dist = signed_distance(pts, "soda_can", OBJECTS["soda_can"].nominal_size, pose)[0]
    np.testing.assert_allclose(dist, [0.9 - radius, 0.9 - length / 2])


@pytest.fixture(scope="module")
def bullet():
    client = p.connect(p.DIRECT)
    yield client
    p.disconnect(client)


def _bullet_shape(client: int, shape: str, dims: tuple[float, ...]) -> int:
    if shape == "sphere":
        return p.createCollisionShape(p.GEOM_SPHERE, radius=dims[0], physicsClientId=client)
    if shape == "cylinder":
        return p.createCollisionShape(p.GEOM_CYLINDER, radius=dims[0], height=dims[1], physicsClientId=client)
    return p.createCollisionShape(p.GEOM_BOX, halfExtents=list(dims), physicsClientId=client)


@pytest.mark.parametrize("name", ["orange", "soda_can", "mug", "cracker_box", "toy_cube"])
def test_matches_pybullet_closest_points(bullet, name):
    cat = OBJECTS[name]
    size = cat.nominal_size * 1.1
    dims = cat.scaled_dims(size)
    rng = np.random.default_rng(len(name))
    body = p.createMultiBody(0.0, _bullet_shape(bullet, cat.shape, dims), physicsClientId=bullet)
    probe = p.createMultiBody(
        0.0, p.createCollisionShape(p.GEOM_SPHERE, radius=PROBE_RADIUS, physicsClientId=bullet), physicsClientId=bullet
    )
    n = 40
    poses = np.concatenate([rng.uniform(-2, 2, (n, 3)), _random_quaternions(rng, n)], axis=1)
    # Probe points outside, at a few distances from the surface along random directions.
    points = poses[:, None, :3] + rng.normal(size=(n, 1, 3)) * rng.uniform(0.3, 1.2, (n, 1, 1))
    # pybullet's cylinder primitive runs along its local Z.
    ours = signed_distance_local(to_local(points, poses), cat.shape, dims, axis=2)[:, 0]
    compared = 0
    for k in range(n):
        if ours[k] < 0.05:
            continue
        p.resetBasePositionAndOrientation(body, poses[k, :3].tolist(), poses[k, 3:].tolist(), physicsClientId=bullet)
        p.resetBasePositionAndOrientation(probe, points[k, 0].tolist(), [0, 0, 0, 1], physicsClientId=bullet)
        closest = p.getClosestPoints(body, probe, 10.0, physicsClientId=bullet)
        theirs = min(c[8] for c in closest) + PROBE_RADIUS
        # Bullet rounds edges and rims by its collision margin (< 1e-3 here); faces are exact.
        assert ours[k] == pytest.approx(theirs, abs=1e-3), (name, k)
        compared += 1
    assert compared >= 10
    p.removeBody(body, physicsClientId=bullet)
    p.removeBody(probe, physicsClientId=bullet)


def test_fingertip_and_palm_distances():
    pose = np.array([[0.0, 0.4, 3.0, 0.0, 0.0, 0.0, 1.0]] * 2)
    size = 0.8  # orange radius 0.4
    tips = np.array(
        [
            [[0.0, 1.0, 3.0], [1.0, 0.4, 3.0], [0.0, 0.4, 3.1], [5, 5, 5], [5, 5, 5]],
            [[0.0, 0.5, 3.0], [2, 2, 2], [2, 2, 2], [5, 5, 5], [5, 5, 5]],
        ]
    )
    np.testing.assert_allclose(fingertip_distance(tips, "orange", size, pose), [0.2, 0.3])
    palm = np.array([[0.3, 2.0, 3.4], [0.0, 9.0, 3.0]])
    np.testing.assert_allclose(palm_xz_distance(palm, pose[:, :3]), [0.5, 0.0])


def test_lying_cylinder_convention_matches_generators_motion():
    """A can rolling along +X has its axis along world Z: the poses of generators.motion
    and the distances here describe the same body."""
    from generators.motion import object_pose
    from schemas.motion import LineToken, Motion

    cat = OBJECTS["soda_can"]
    size = cat.nominal_size
    radius, length = cat.scaled_dims(size)
    line = Motion.of(LineToken(start=(0.0, 4.0), direction=0.0, speed=1.0, acceleration=0.0, duration=2.0))
    poses, _ = object_pose(line, cat, size, np.array([0.0, 0.7, 1.3]))
    centre = poses[:, None, :3]
    probes = centre + np.array([[0.0, 0.0, length / 2 + 0.2], [0.0, radius + 0.2, 0.0], [radius + 0.2, 0.0, 0.0]])
    np.testing.assert_allclose(signed_distance(probes, "soda_can", size, poses), 0.2, atol=1e-9)
