"""The analytic visibility test against the renderer's segmentation masks, and the
guarantee that the resting hand never hides a recipe object while it is observed."""

from __future__ import annotations

import numpy as np
import pytest

from generators.camera import unproject_to_plane
from generators.grids import OBJECT_NAMES, SIZE_FACTORS
from generators.hand import REST_JOINTS, REST_PALM
from generators.recipe import slice_specs
from generators.render import Renderer
from generators.visibility import (
    hand_parts,
    object_surface_points,
    observe_visibility,
    rest_shadow_z,
    visible_fraction,
)
from pipeline.stages.episode import object_trajectory
from schemas.objects import OBJECTS
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
