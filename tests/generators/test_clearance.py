"""Clearance to obstacles: exact box signed distances, and the hand's and the object's
distances to boxes checked against dense point samples of their surfaces."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial import cKDTree

from generators.clearance import (
    WRIST_LENGTH,
    WRIST_RADIUS,
    box_signed_distance,
    hand_clearance,
    hand_clearances,
    object_clearance,
    obstacle_corners,
    obstacle_rotation,
)
from generators.hand import (
    FINGER_RADII,
    JOINT_LOWER,
    JOINT_UPPER,
    PALM_HALF_EXTENTS,
    REST_JOINTS,
    REST_PALM,
    WRIST_OFFSET,
    chain_frames,
)
from generators.hand_urdf import hand_urdf
from schemas.errors import SpecError
from schemas.objects import OBJECTS
from schemas.obstacles import Obstacle
from schemas.rotations import euler_to_matrix, quaternion_to_matrix

#: Spacing of the reference samples; a sampled surface's minimum exceeds the true one by
#: at most the largest distance from a surface point to its nearest sample.
STEP = 0.01
SAMPLING_ERROR = 0.008


def grid(lo: float, hi: float, step: float = STEP) -> np.ndarray:
    return np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / step)) + 1))


def box_surface(half, step: float = STEP) -> np.ndarray:
    """Points on a centred box's surface, no two neighbours farther apart than ``step``."""
    out = []
    for axis in range(3):
        u, v = (k for k in range(3) if k != axis)
        a, b = np.meshgrid(grid(-half[u], half[u], step), grid(-half[v], half[v], step))
        for sign in (-1.0, 1.0):
            p = np.zeros(a.shape + (3,))
            p[..., u], p[..., v], p[..., axis] = a, b, sign * half[axis]
            out.append(p.reshape(-1, 3))
    return np.concatenate(out)


def cylinder_surface(radius: float, half_length: float, step: float = STEP) -> np.ndarray:
    """Points on a centred cylinder along Z: its side and both caps."""
    angles = np.linspace(0.0, 2 * np.pi, int(np.ceil(2 * np.pi * radius / step)) + 1, endpoint=False)
    a, z = np.meshgrid(angles, grid(-half_length, half_length, step))
    side = np.stack([radius * np.cos(a), radius * np.sin(a), z], axis=-1).reshape(-1, 3)
    a, r = np.meshgrid(angles, grid(0.0, radius, step))
    caps = [np.stack([r * np.cos(a), r * np.sin(a), np.full_like(r, s * half_length)], -1).reshape(-1, 3) for s in (-1, 1)]
    return np.concatenate([side] + caps)


def sphere_surface(radius: float, step: float = STEP) -> np.ndarray:
    n = int(4 * np.pi * radius**2 / step**2 * 1.5) + 50
    k = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1 - 2 * k / n), np.pi * (1 + 5**0.5) * k
    return radius * np.stack([np.cos(azimuth) * np.sin(polar), np.cos(polar), np.sin(azimuth) * np.sin(polar)], -1)


def capsule_surface(p0, p1, radius: float, step: float = STEP) -> np.ndarray:
    """Points on a capsule's side and on the balls at its ends."""
    axis = p1 - p0
    length = np.linalg.norm(axis)
    w = axis / length
    u = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    side = cylinder_surface(radius, length / 2, step)
    side = side[np.isclose(np.hypot(side[:, 0], side[:, 1]), radius)]
    side = (p0 + p1) / 2 + side @ np.stack([u, np.cross(w, u), w])
    ball = sphere_surface(radius, step)
    return np.concatenate([side, p0 + ball, p1 + ball])


def hand_surface(palm: np.ndarray, joints: np.ndarray, side: str) -> np.ndarray:
    """Dense points on the hand's surface: palm box, wrist cylinder, finger capsules."""
    rot = euler_to_matrix(palm[3:])
    wrist_centre = np.asarray(WRIST_OFFSET) - [0.0, 0.0, WRIST_LENGTH / 2]
    local = [box_surface(PALM_HALF_EXTENTS), wrist_centre + cylinder_surface(WRIST_RADIUS, WRIST_LENGTH / 2)]
    points = [palm[:3] + np.concatenate(local) @ rot.T]
    chain = chain_frames(palm[None], joints[None], side)[0][0]
    for finger in range(5):
        for k in range(3):
            points.append(capsule_surface(chain[finger, k], chain[finger, k + 1], FINGER_RADII[finger]))
    return np.concatenate(points)


def random_obstacle(rng: np.random.Generator, near=(0.0, 4.0)) -> Obstacle:
    return Obstacle(
        str(rng.choice(["crate", "book", "brick"])),
        (near[0] + rng.uniform(-1.5, 1.5), near[1] + rng.uniform(-1.5, 1.5)),
        tuple(float(v) for v in rng.uniform(0.08, 1.0, 3)),
        float(rng.uniform(-np.pi, np.pi)),
    )


# box signed distance --------------------------------------------------------------
def test_signed_distance_matches_a_dense_surface_sample_inside_and_out():
    rng = np.random.default_rng(0)
    for _ in range(5):
        obstacle = random_obstacle(rng)
        centre = np.array([obstacle.centre[0], obstacle.half_extents[1], obstacle.centre[1]])
        surface = centre + box_surface(obstacle.half_extents, 0.005) @ obstacle_rotation(obstacle).T
        points = centre + rng.normal(0.0, 0.8, (300, 3))
        exact = box_signed_distance(points, obstacle)
        nearest, _ = cKDTree(surface).query(points)
        local = (points - centre) @ obstacle_rotation(obstacle)
        inside = np.all(np.abs(local) < obstacle.half_extents, axis=1)
        assert np.array_equal(exact < 0, inside)
        assert np.all(np.abs(np.abs(exact) - nearest) <= 0.004)
        assert np.all(np.abs(exact) <= nearest + 1e-12)


def test_signed_distance_on_faces_edges_corners_and_centre():
    obstacle = Obstacle("brick", (1.0, 4.0), (0.5, 0.3, 0.2), 0.0)
    c = np.array([1.0, 0.3, 4.0])
    cases = {
        (0.0, 0.0, 0.0): -0.2,  # centre: the nearest faces are the thin ones
        (0.5, 0.0, 0.0): 0.0,  # on a face
        (0.5, 0.3, 0.0): 0.0,  # on an edge
        (0.5, 0.3, 0.2): 0.0,  # a corner
        (0.8, 0.0, 0.0): 0.3,  # beyond a face
        (0.8, 0.7, 0.0): 0.5,  # beyond an edge: (0.3, 0.4)
        (0.8, 0.7, -0.2 - 1.2): 1.3,  # beyond a corner: (0.3, 0.4, 1.2)
        (0.4, 0.0, 0.0): -0.1,  # just inside
    }
    points = c + np.array(list(cases))
    assert np.allclose(box_signed_distance(points, obstacle), list(cases.values()), atol=1e-12)
    assert box_signed_distance(points[:3].reshape(3, 1, 3), obstacle).shape == (3, 1)
    assert box_signed_distance(c, obstacle).shape == ()


def test_yaw_turns_the_box_about_plus_y_as_ry():
    """A positive yaw turns the box's +X toward world -Z: R = Ry(yaw), as euler_to_matrix
    and pybullet's quaternion (0, sin(yaw/2), 0, cos(yaw/2)) turn it."""
    obstacle = Obstacle("book", (0.0, 4.0), (1.0, 0.15, 0.2), np.pi / 2)
    c = np.array([0.0, 0.15, 4.0])
    rot = obstacle_rotation(obstacle)
    assert np.allclose(rot, euler_to_matrix(np.array([0.0, np.pi / 2, 0.0])))
    assert np.allclose(rot, quaternion_to_matrix(np.array([0.0, np.sin(np.pi / 4), 0.0, np.cos(np.pi / 4)])))
    assert np.allclose(rot @ [1.0, 0.0, 0.0], [0.0, 0.0, -1.0])
    along_z, along_x = c + [0.0, 0.0, 1.5], c + [0.5, 0.0, 0.0]
    assert np.allclose(box_signed_distance(np.array([along_z, along_x]), obstacle), [0.5, 0.3])
    corners = obstacle_corners(obstacle)
    assert np.allclose(np.ptp(corners, axis=0), [0.4, 0.3, 2.0])
    assert np.allclose(corners.min(axis=0)[1], 0.0), "the box rests on the table"
    turned = Obstacle("book", (0.0, 4.0), (1.0, 0.15, 0.2), 0.3)
    assert np.allclose(box_signed_distance(obstacle_corners(turned), turned), 0.0, atol=1e-12)


# the hand -----------------------------------------------------------------------------
def test_the_wrist_and_palm_match_the_urdf():
    text = hand_urdf("right")
    wrist = re.search(r'<link name="wrist">.*?<origin xyz="0 0 ([-\d.]+)"/><geometry><cylinder radius="([\d.]+)" length="([\d.]+)"', text)
    assert wrist is not None
    assert float(wrist.group(1)) == pytest.approx(-WRIST_LENGTH / 2)
    assert float(wrist.group(2)) == pytest.approx(WRIST_RADIUS)
    assert float(wrist.group(3)) == pytest.approx(WRIST_LENGTH)
    palm = re.search(r'<link name="palm">.*?<box size="([\d. ]+)"', text)
    assert [float(v) / 2 for v in palm.group(1).split()] == pytest.approx(list(PALM_HALF_EXTENTS))


def random_hands(rng: np.random.Generator, n: int):
    for i in range(n):
        palm = np.array([rng.uniform(-1.0, 1.0), rng.uniform(0.3, 2.0), rng.uniform(2.5, 5.5), *rng.normal(0, 0.6, 3)])
        yield palm, rng.uniform(JOINT_LOWER, JOINT_UPPER), ("right", "left")[i % 2]


def test_hand_clearance_matches_a_dense_sample_of_the_hands_surface():
    rng = np.random.default_rng(1)
    hands = list(random_hands(rng, 8))
    obstacles = [random_obstacle(rng) for _ in range(3)]
    checked = 0
    for palm, joints, side in hands:
        exact = hand_clearances(palm[None], joints[None], side, obstacles)[0]
        surface = hand_surface(palm, joints, side)
        for k, obstacle in enumerate(obstacles):
            reference = box_signed_distance(surface, obstacle).min()
            if reference > SAMPLING_ERROR:
                assert exact[k] <= reference + 1e-9, "a sampled point is nearer than the exact distance"
                assert exact[k] >= reference - SAMPLING_ERROR
                checked += 1
            elif reference < -SAMPLING_ERROR:
                assert exact[k] <= 0.0
    assert checked >= 12


def test_hand_clearance_near_contact_is_the_gap_to_a_facing_wall():
    """A brick whose face lies ``gap`` beyond the hand's lowest (or leftmost, rightmost,
    farthest) sampled point, centred on it: every part of the hand is at least that far
    from it, and that point is exactly that far, so the clearance is the gap, less the
    little by which the hand's true extreme lies beyond the sample's."""
    rng = np.random.default_rng(2)
    for palm, joints, side in random_hands(rng, 5):
        palm[1] += 1.0
        surface = hand_surface(palm, joints, side)
        top = surface[:, 1].max() + 0.5
        for gap in (0.01, 0.04, 0.12, -0.02):
            below = surface[surface[:, 1].argmin()]
            walls = [Obstacle("brick", (below[0], below[2]), (0.2, (below[1] - gap) / 2, 0.2), float(rng.uniform(-1, 1)))]
            for axis, sign in ((0, -1.0), (0, 1.0), (2, 1.0)):
                s = surface[(sign * surface[:, axis]).argmax()]
                centre = s[[0, 2]] + sign * (gap + 0.3) * (np.arange(3)[[0, 2]] == axis)
                half = (0.3, top / 2, 1.0) if axis == 0 else (1.0, top / 2, 0.3)
                walls.append(Obstacle("crate", tuple(centre), half, 0.0))
            got = hand_clearances(palm[None], joints[None], side, walls)[0]
            if gap > 0:  # a sampled extreme lies within 1e-3 of the true one on these shapes
                assert np.all(got <= gap + 1e-9) and np.all(got >= gap - 1e-3), (gap, got)
            else:
                assert np.all(got <= 0.0), got


def test_a_hand_resting_on_a_box_touches_it():
    """A brick under the palm's centre: the palm's flat bottom face is the nearest part."""
    hy = 0.3
    brick = Obstacle("brick", (0.0, 4.0), (0.1, hy, 0.1), 0.0)
    palm_bottom = PALM_HALF_EXTENTS[1]
    heights = 2 * hy + palm_bottom + np.array([0.05, 0.01, 0.0, -1e-6, -0.05])
    palms = np.array([[0.0, y, 4.0, 0.0, 0.0, 0.0] for y in heights])
    got = hand_clearance(palms, np.repeat(REST_JOINTS[None], len(palms), axis=0), "right", [brick])
    assert got[:2] == pytest.approx([0.05, 0.01], abs=1e-7)
    assert abs(got[2]) <= 1e-7
    assert np.all(got[3:] <= 0.0)


def test_hand_clearance_without_obstacles_is_infinite():
    palms = np.repeat(REST_PALM[None], 4, axis=0)
    joints = np.repeat(REST_JOINTS[None], 4, axis=0)
    got = hand_clearance(palms, joints, "left", ())
    assert got.shape == (4,) and np.all(np.isinf(got)) and np.all(got > 0)
    assert hand_clearances(palms, joints, "left", []).shape == (4, 0)


def test_hand_clearance_is_the_minimum_over_obstacles_and_vectorised():
    rng = np.random.default_rng(3)
    hands = list(random_hands(rng, 20))
    palms = np.array([h[0] for h in hands])
    joints = np.array([h[1] for h in hands])
    obstacles = [random_obstacle(rng) for _ in range(3)]
    together = hand_clearances(palms, joints, "right", obstacles)
    assert together.shape == (20, 3)
    assert np.array_equal(hand_clearance(palms, joints, "right", obstacles), together.min(axis=1))
    for k, obstacle in enumerate(obstacles):
        assert np.allclose(hand_clearance(palms, joints, "right", [obstacle]), together[:, k], atol=1e-9)
    alone = np.array([hand_clearance(palms[i : i + 1], joints[i : i + 1], "right", obstacles)[0] for i in range(5)])
    assert np.allclose(alone, together.min(axis=1)[:5], atol=1e-9)


# the object -------------------------------------------------------------------------
def object_surface(name: str, size: float, pose: np.ndarray) -> np.ndarray:
    cat = OBJECTS[name]
    dims = cat.scaled_dims(size)
    if cat.shape == "sphere":
        local = sphere_surface(dims[0], 0.005)
    elif cat.shape == "box":
        local = box_surface(dims)
    else:
        local = cylinder_surface(dims[0], dims[1] / 2)  # along Z: turn onto the category's axis
        local = local[:, [2, 0, 1]] if cat.lying else local[:, [1, 2, 0]]
    return pose[:3] + local @ quaternion_to_matrix(pose[3:]).T


@pytest.mark.parametrize("name", ["orange", "soda_can", "water_bottle", "mug", "cracker_box", "toy_cube"])
def test_object_clearance_matches_a_dense_sample_of_its_surface(name):
    rng = np.random.default_rng(sum(map(ord, name)))
    cat = OBJECTS[name]
    size = cat.nominal_size
    obstacles = [random_obstacle(rng, near=(0.0, 4.0)) for _ in range(3)]
    poses = []
    for i in range(6):
        quat = rng.normal(size=4) if i % 2 else np.array([0.0, 0.0, 0.0, 1.0])
        poses.append(np.array([rng.uniform(-1.5, 1.5), cat.half_height(size) + rng.uniform(0, 0.5), rng.uniform(2.5, 5.5), *quat / np.linalg.norm(quat)]))
    poses = np.array(poses)
    got = object_clearance(name, size, poses, obstacles)
    for pose, value in zip(poses, got):
        surface = object_surface(name, size, pose)
        reference = min(box_signed_distance(surface, o).min() for o in obstacles)
        if reference > SAMPLING_ERROR:
            assert reference - SAMPLING_ERROR <= value <= reference + 1e-9, (value, reference)
        elif reference < -SAMPLING_ERROR:
            assert value <= 0.0


def test_object_clearance_of_objects_beside_and_inside_a_box():
    crate = Obstacle("crate", (0.0, 4.0), (0.6, 0.5, 0.6), 0.0)
    ball = OBJECTS["orange"]
    r = ball.scaled_dims(0.8)[0]
    poses = np.array([[0.6 + r + gap, r, 4.0, 0.0, 0.0, 0.0, 1.0] for gap in (0.3, 0.0, -0.1)])
    assert object_clearance("orange", 0.8, poses, [crate]) == pytest.approx([0.3, 0.0, -0.1], abs=1e-12)
    cube = OBJECTS["toy_cube"].scaled_dims(0.6)
    beside = np.array([[0.6 + cube[0] + 0.25, cube[1], 4.0, 0.0, 0.0, 0.0, 1.0], [0.0, 0.5, 4.0, 0.0, 0.0, 0.0, 1.0]])
    got = object_clearance("toy_cube", 0.6, beside, [crate])
    assert got[0] == pytest.approx(0.25, abs=1e-7) and got[1] < 0.0
    assert np.all(np.isinf(object_clearance("mug", 0.84, beside, ())))


def test_a_cylinder_lying_across_a_thin_slab_overlaps_it():
    """No box edge reaches the cylinder and no support line meets the slab: only the slab
    cut of the cylinder's axis finds this overlap."""
    slab = Obstacle("book", (0.0, 4.0), (3.0, 0.05, 3.0), 0.0)
    can = OBJECTS["paper_roll"]
    r = can.scaled_dims(1.1)[0]
    heights = 0.1 + r + np.array([-0.015, -0.001, 0.001, 0.2])
    poses = np.array([[0.0, y, 4.0, 0.0, 0.0, 0.0, 1.0] for y in heights])
    got = object_clearance("paper_roll", 1.1, poses, [slab])
    assert np.all(got[:2] <= 0.0)
    assert got[2:] == pytest.approx([0.001, 0.2], abs=1e-7)


def test_bad_arguments_are_spec_errors():
    brick = Obstacle("brick", (0.0, 4.0), (0.2, 0.2, 0.2))
    with pytest.raises(SpecError, match="obstacle"):
        box_signed_distance(np.zeros(3), "brick")
    with pytest.raises(SpecError, match="points"):
        box_signed_distance(np.zeros(4), brick)
    with pytest.raises(SpecError, match="obstacles"):
        hand_clearance(REST_PALM, REST_JOINTS, "right", brick)
    with pytest.raises(SpecError, match=r"obstacles\[1\]"):
        hand_clearance(REST_PALM, REST_JOINTS, "right", [brick, {"category": "crate"}])
    with pytest.raises(SpecError, match="palm_pose"):
        hand_clearance(np.zeros(5), REST_JOINTS, "right", [brick])
    with pytest.raises(SpecError, match="poses"):
        object_clearance("orange", 0.8, np.zeros(6), [brick])
    with pytest.raises(SpecError, match="unknown object"):
        object_clearance("anvil", 0.8, np.zeros(7), [brick])
