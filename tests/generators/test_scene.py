"""The pybullet scene: table and floor where the camera expects them, object frames
(lying cylinders along X), markings, hands from the URDF, visibility switching."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

from generators.camera import project
from generators.hand import JOINT_NAMES, REST_JOINTS, REST_PALM
from generators.render import Renderer
from generators.scene import (
    FLOOR_RGBA,
    LYING_AXIS,
    MARKING_RGBA,
    TABLE_BORDER,
    TABLE_BORDER_RGBA,
    TABLE_RGBA,
    build_object,
    build_static,
    load_hand,
    object_parts,
    set_hand_pose,
)
from schemas.objects import OBJECTS
from schemas.scene import TABLE_X, TABLE_Z
from tests.generators.colours import colour_mask, matches

RES = 160


def pixel_of(point) -> tuple[int, int]:
    (col, row), _ = project(np.asarray(point, dtype=np.float64), RES, RES)
    return int(row), int(col)


@pytest.fixture(scope="module")
def renderer():
    with Renderer(RES) as r:
        yield r


@pytest.fixture()
def client():
    c = p.connect(p.DIRECT)
    yield c
    p.disconnect(c)


def test_table_border_and_floor_are_where_the_camera_expects(renderer):
    renderer.set_scene(None, None, None)
    img = renderer.render()
    (x0, x1), z1 = TABLE_X, TABLE_Z[1]
    assert matches(img[pixel_of((0.0, 0.0, 4.5))], TABLE_RGBA)
    assert matches(img[pixel_of((x0 + 1.5, 0.0, z1 - 1.0))], TABLE_RGBA)
    assert matches(img[pixel_of((0.0, 0.0, z1 - TABLE_BORDER / 2))], TABLE_BORDER_RGBA)
    assert matches(img[pixel_of((x1 - TABLE_BORDER / 2, 0.0, 6.0))], TABLE_BORDER_RGBA)
    assert matches(img[2, RES // 2], FLOOR_RGBA)  # beyond the table's far edge
    assert not matches(img[pixel_of((0.0, 0.0, 4.5))], FLOOR_RGBA)


def bbox(mask: np.ndarray) -> tuple[int, int]:
    rows, cols = np.nonzero(mask)
    return cols.max() - cols.min() + 1, rows.max() - rows.min() + 1


def test_lying_cylinders_lie_along_x_at_identity(renderer):
    assert LYING_AXIS == (1.0, 0.0, 0.0)
    cat = OBJECTS["water_bottle"]
    size = cat.nominal_size
    y = cat.half_height(size)
    renderer.set_scene("water_bottle", size, None)
    turned = [0.0, np.sin(np.pi / 4), 0.0, np.cos(np.pi / 4)]  # 90 degrees about Y: axis along Z
    shapes = []
    for quat in ([0.0, 0.0, 0.0, 1.0], turned):
        img = renderer.render([0.0, y, 3.0, *quat])
        mask = colour_mask(img, cat.rgba)
        shapes.append(bbox(mask))
    (w0, h0), (w1, h1) = shapes
    assert w0 > 1.5 * h0  # across the view
    assert h1 > w1  # along the view


def test_upright_cylinders_stand_and_show_their_opening(renderer):
    for name in ("mug", "cup"):
        cat = OBJECTS[name]
        size = cat.nominal_size
        top = cat.half_height(size) * 2
        renderer.set_scene(name, size, None)
        img = renderer.render([0.0, cat.half_height(size), 3.0, 0.0, 0.0, 0.0, 1.0])
        assert matches(img[pixel_of((0.0, top, 3.0))], MARKING_RGBA[name]), name


def test_rolling_objects_carry_markings_and_every_part_has_a_known_colour():
    for name, cat in OBJECTS.items():
        parts = object_parts(name, cat.nominal_size)
        assert parts[0].rgba == cat.rgba
        assert all(part.rgba in (cat.rgba, MARKING_RGBA[name]) for part in parts)
        markings = sum(part.rgba == MARKING_RGBA[name] for part in parts)
        assert markings >= (2 if cat.rolling else 1), name


def test_rolling_shows_in_the_image(renderer):
    """A ball turned about a horizontal axis looks different: its seams move."""
    cat = OBJECTS["tennis_ball"]
    size = 1.2
    renderer.set_scene("tennis_ball", size, None)
    y = cat.half_height(size)
    images = [
        renderer.render([0.0, y, 2.5, np.sin(a / 2), 0.0, 0.0, np.cos(a / 2)]) for a in (0.0, 0.5)
    ]
    assert (images[0] != images[1]).any(axis=2).sum() > 10


def test_static_bodies_come_first_and_objects_are_posable(client):
    static = build_static(client)
    assert list(static) == list(range(len(static)))
    body = build_object(client, "soda_can", 0.7, position=(1.0, 0.35, 3.0))
    assert body == len(static)
    pos, _ = p.getBasePositionAndOrientation(body, physicsClientId=client)
    assert np.allclose(pos, (1.0, 0.35, 3.0))


def test_hand_loads_from_the_urdf_with_the_palm_at_the_base(client):
    body, indices = load_hand(client, "right")
    assert len(indices) == len(JOINT_NAMES) == 15
    names = [p.getJointInfo(body, int(i), physicsClientId=client)[1].decode() for i in indices]
    assert names == list(JOINT_NAMES)
    palm = np.array([1.0, 2.0, 3.0, 0.1, -0.2, 0.3])
    joints = np.linspace(0.0, 0.9, 15)
    set_hand_pose(client, body, indices, palm, joints)
    pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=client)
    assert np.allclose(pos, palm[:3])
    assert np.allclose(orn, p.getQuaternionFromEuler(palm[3:].tolist()))
    got = [p.getJointState(body, int(i), physicsClientId=client)[0] for i in indices]
    assert np.allclose(got, joints)


def test_switching_scenes_gives_back_the_same_frame(renderer):
    renderer.set_scene(None, None, "right")
    with_hand = renderer.render(None, REST_PALM, REST_JOINTS)
    renderer.set_scene(None, None, None)
    plate = renderer.render()
    assert not np.array_equal(with_hand, plate)
    renderer.set_scene(None, None, "left")
    renderer.set_scene(None, None, "right")
    assert np.array_equal(renderer.render(None, REST_PALM, REST_JOINTS), with_hand)


def test_the_hand_urdf_is_written_once_per_process_and_again_if_removed(client):
    import os

    from generators.scene import hand_urdf_file

    path = hand_urdf_file("left")
    assert hand_urdf_file("left") == path and hand_urdf_file("right") != path
    first, _ = load_hand(client, "left")
    os.unlink(path)
    again = hand_urdf_file("left")
    assert os.path.exists(again)
    second, _ = load_hand(client, "left")
    assert p.getNumJoints(first, physicsClientId=client) == p.getNumJoints(second, physicsClientId=client)
