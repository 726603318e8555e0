"""The analytic visibility test against the renderer's segmentation masks, and the
guarantee that the resting hand never hides a recipe object while it is observed;
obstacles hiding the object."""

from __future__ import annotations

import numpy as np
import pytest

from generators.camera import unproject_to_plane
from generators.grids import OBJECT_NAMES, SIZE_FACTORS
from generators.ground_truth import object_trajectory
from generators.hand import REST_JOINTS, REST_PALM
from generators.recipe import slice_specs
from generators.render import Renderer
from generators.visibility import (
    first_hidden_frame,
    hand_parts,
    object_surface_points,
    observe_visibility,
    obstacle_hides,
    rest_shadow_z,
    visible_fraction,
)
from schemas.errors import SpecError
from schemas.objects import OBJECTS
from schemas.obstacles import Obstacle
from schemas.slices import ATOMIC_SLICES

RESOLUTION = 224
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def _pose(name: str, size: float, x: float, z: float) -> np.ndarray:
    return np.array([x, OBJECTS[name].half_height(size), z, *IDENTITY])


@pytest.fixture(scope="module")
def renderer():
    with Renderer(RESOLUTION) as r:
        yield r


def _segmented(renderer: Renderer, name: str, size: float, side: str, pose, palm, joints) -> float:
    renderer.set_scene(name, size, side)
    shown, alone = renderer.object_pixels(pose, palm, joints)
    assert alone > 50, "the case must show the object"
    return shown / alone


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_the_resting_hand_hides_no_pixel_of_an_object_beyond_its_shadow(renderer, name, side):
    """The recipe keeps every footprint beyond rest_shadow_z; there, the segmentation mask
    shows every pixel of the object (the largest recipe size, at the nearest it may be)."""
    size = round(OBJECTS[name].nominal_size * max(SIZE_FACTORS), 4)
    dims = OBJECTS[name].scaled_dims(size)
    reach = {"sphere": dims[0], "box": float(np.hypot(dims[0], dims[-1]))}.get(OBJECTS[name].shape)
    if reach is None:
        reach = float(np.hypot(dims[0], dims[1] / 2.0)) if OBJECTS[name].lying else dims[0]
    for x in (-1.0, 0.0, 1.0):
        pose = _pose(name, size, x, rest_shadow_z() + reach + 1e-3)
        renderer.set_scene(name, size, side)
        shown, alone = renderer.object_pixels(pose, REST_PALM, REST_JOINTS)
        assert shown == alone > 0
        assert observe_visibility(name, size, side, pose[None])[0] == 1.0


CASES = [
    # object under the resting fingers, at several depths
    ("tennis_ball", 0.67, "right", (0.0, 0.2), None),
    ("tennis_ball", 0.67, "left", (0.0, 0.0), None),
    ("water_bottle", 0.7, "right", (0.3, 0.3), None),
    ("cracker_box", 1.6, "left", (0.0, 0.1), None),
    ("mug", 0.84, "right", (0.2, -0.2), None),
    # the hand over the object, fingers half closed
    ("tennis_ball", 0.67, "left", (0.0, 3.2), ((0.2, 1.2, 2.8), 0.5)),
    ("water_bottle", 0.7, "right", (0.3, 3.3), ((0.5, 1.2, 2.9), 0.5)),
    ("orange", 0.8, "right", (-1.0, 4.0), ((-0.9, 1.4, 3.2), 0.2)),
]


@pytest.mark.parametrize("name, size, side, xz, hand", CASES)
def test_the_analytic_visible_fraction_agrees_with_segmentation_masks(renderer, name, size, side, xz, hand):
    pose = _pose(name, size, *xz)
    if hand is None:
        palm, joints = REST_PALM, REST_JOINTS
    else:
        palm = np.array([*hand[0], 0.0, 0.0, 0.0])
        joints = REST_JOINTS + hand[1]
    seg = _segmented(renderer, name, size, side, pose, palm, joints)
    analytic = visible_fraction(object_surface_points(name, size, pose), hand_parts(palm, joints, side), RESOLUTION)
    assert abs(analytic - seg) <= 0.08, (analytic, seg)
    assert analytic <= seg + 0.02, "the analytic test errs toward calling the object hidden"


def test_an_object_half_outside_the_image_is_half_visible():
    size = 0.8
    radius = OBJECTS["orange"].scaled_dims(size)[0]
    edge = unproject_to_plane(np.array([[RESOLUTION, RESOLUTION / 2]]), RESOLUTION, RESOLUTION, radius)[0]
    pose = np.array([edge[0], radius, edge[2], *IDENTITY])
    fraction = visible_fraction(object_surface_points("orange", size, pose), [], RESOLUTION)
    assert 0.45 <= fraction <= 0.55
    assert visible_fraction(object_surface_points("orange", size, pose + [-3.0, 0, 0, 0, 0, 0, 0]), []) == 1.0


@pytest.mark.parametrize("slice_name", ATOMIC_SLICES + ("test-1k",))
def test_recipe_episodes_show_their_object_in_every_observe_frame(slice_name):
    for spec in slice_specs(slice_name, 24):
        poses, _, _ = object_trajectory(spec)
        fractions = observe_visibility(spec.object, spec.object_size, spec.hand, poses[: spec.observe_frames])
        assert np.all(fractions == 1.0), spec.episode_id


OBSTACLE_CASES = [
    # in front of the object: a wall hiding about half a ball, a slab across a box, a turned brick
    ("orange", 0.8, (0.0, 5.0), Obstacle("crate", (0.0, 3.6), (0.6, 0.9, 0.4), 0.0)),
    ("soda_can", 0.66, (-1.0, 4.0), Obstacle("brick", (-1.3, 3.0), (0.55, 0.8, 0.28), 0.3)),
    ("cracker_box", 1.6, (0.0, 5.5), Obstacle("book", (0.35, 4.0), (0.05, 1.5, 0.4), 0.0)),
    ("sugar_box", 0.9, (1.5, 5.0), Obstacle("crate", (1.0, 3.8), (0.6, 0.8, 0.6), 0.8)),
    ("mug", 0.84, (1.0, 4.5), Obstacle("book", (0.6, 3.6), (0.75, 0.5, 0.3), -0.4)),
    # behind it, their silhouettes overlapping: nothing hidden
    ("orange", 0.8, (0.0, 5.0), Obstacle("crate", (0.0, 5.9), (0.6, 2.0, 0.4), 0.0)),
    ("cracker_box", 1.6, (0.0, 5.5), Obstacle("book", (0.35, 6.2), (0.05, 3.0, 0.3), 0.0)),
]


@pytest.mark.parametrize("name, size, xz, obstacle", OBSTACLE_CASES)
def test_obstacles_hide_the_object_as_segmentation_masks_do(renderer, name, size, xz, obstacle):
    pose = _pose(name, size, *xz)
    renderer.set_scene(name, size, "right", (obstacle,))
    shown, alone = renderer.object_pixels(pose, REST_PALM, REST_JOINTS)
    assert alone > 50
    seg = shown / alone
    points = object_surface_points(name, size, pose)
    hand = hand_parts(REST_PALM, REST_JOINTS, "right")
    analytic = visible_fraction(points, hand, RESOLUTION, (obstacle,))
    assert abs(analytic - seg) <= 0.08, (analytic, seg)
    assert analytic <= seg + 0.02, "the analytic test errs toward calling the object hidden"
    in_front = obstacle.centre[1] < xz[1]
    assert obstacle_hides(points, obstacle) == in_front
    if in_front:
        assert analytic < 0.95 and seg < 0.95
        assert visible_fraction(points, hand, RESOLUTION) == 1.0, "the obstacle, not the hand, hides it"
    else:
        assert analytic == 1.0 and shown == alone


def test_an_object_touching_an_obstacle_counts_as_hidden_by_it():
    pose = _pose("toy_cube", 0.6, 0.0, 5.0)
    points = object_surface_points("toy_cube", 0.6, pose)
    assert not obstacle_hides(points, Obstacle("crate", (0.0, 6.0), (0.6, 2.0, 0.6), 0.0)), "a gap behind it"
    assert obstacle_hides(points, Obstacle("crate", (0.0, 5.9), (0.6, 2.0, 0.6), 0.0)), "faces touch"
    assert obstacle_hides(points, Obstacle("crate", (0.0, 5.85), (0.6, 2.0, 0.6), 0.0)), "they overlap"


def test_observe_frames_behind_an_obstacle_are_refused():
    name, size = "tennis_ball", 0.67
    poses = np.array([_pose(name, size, x, 5.0) for x in np.linspace(-3.0, 3.0, 13)])
    wall = Obstacle("crate", (0.0, 3.6), (0.8, 1.0, 0.4), 0.0)
    assert first_hidden_frame(name, size, "right", poses) is None
    assert np.all(observe_visibility(name, size, "right", poses, obstacles=(Obstacle("book", (3.0, 8.0), (0.3, 0.15, 0.3)),)) == 1.0)
    fractions = observe_visibility(name, size, "right", poses, obstacles=(wall,))
    assert fractions[0] == 1.0 and fractions[6] < 0.5
    frame, fraction = first_hidden_frame(name, size, "right", poses, obstacles=[wall])
    assert 0 < frame <= 6 and fraction == fractions[frame] < 0.5
    with pytest.raises(SpecError, match="obstacles"):
        observe_visibility(name, size, "right", poses, obstacles=wall)
