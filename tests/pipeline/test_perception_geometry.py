"""Perception's geometry helpers give the bits of the computations they replaced: the
monotone-chain hull is Qhull's, the separable edge test is the per-pixel one, a
windowed hand mask is the full mask cut to the window, cropped template matching is
full-frame matching, the cached unprojection is the camera's, and the size estimate
follows its samples."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull, QhullError

from generators.camera import unproject_to_plane
from generators.hand import REST_JOINTS, REST_PALM, forward_kinematics
from pipeline.policies import camera_model, hand_shape, silhouette
from pipeline.policies.hand_shape import HandShape, hand_mask
from pipeline.policies.perception import ObjectLocator
from pipeline.policies.silhouette import match_template, template
from schemas.objects import OBJECTS
from tests.pipeline.test_policies import _scene

RES = 224


def _qhull(points: np.ndarray) -> np.ndarray:
    try:
        return points[ConvexHull(points).vertices]
    except QhullError:
        return np.empty((0, 2))


def _same_cycle(a: np.ndarray, b: np.ndarray) -> bool:
    return len(a) == len(b) and (len(a) == 0 or any(np.array_equal(np.roll(a, k, axis=0), b) for k in range(len(b))))


def _point_sets(rng: np.random.Generator, count: int = 300):
    for _ in range(count):
        points = rng.normal(size=(int(rng.integers(3, 40)), 2)) * rng.uniform(1.0, 60.0)
        yield points
        yield np.round(points)  # repeated and collinear points
    for name in sorted(OBJECTS):
        category = OBJECTS[name]
        for heading in silhouette.headings(category):
            centre = np.array([rng.uniform(-3, 3), category.half_height(category.nominal_size), rng.uniform(1.5, 7.5)])
            body = silhouette.surface_points(category, category.nominal_size, heading)
            yield camera_model.project(centre + body, RES, RES)[0]


def test_convex_hull_is_qhulls_counterclockwise_vertices():
    rng = np.random.default_rng(7)
    for points in _point_sets(rng):
        ours = hand_shape.convex_hull(points)
        assert _same_cycle(ours, _qhull(points)), points.tolist()
        if len(ours):
            assert hand_shape.signed_area(ours) > 0


@pytest.mark.parametrize("points", [np.zeros((5, 2)), np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])])
def test_degenerate_hulls_are_empty_as_qhull_refuses_them(points):
    assert hand_shape.convex_hull(points).shape == (0, 2) == _qhull(points).shape


def _per_pixel_depth(xs: np.ndarray, ys: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """The edge test as it was written, one (h, w, k) array."""
    px = np.stack(np.meshgrid(xs, ys), axis=-1)
    a, b = hull, np.roll(hull, -1, axis=0)
    edge = b - a
    length = np.maximum(np.linalg.norm(edge, axis=1), 1e-12)
    rel = px[..., None, :] - a
    cross = (edge[:, 0] * rel[..., 1] - edge[:, 1] * rel[..., 0]) / length
    sign = 1.0 if hand_shape.signed_area(hull) > 0 else -1.0
    return (sign * cross).min(axis=-1)


def test_separable_edge_test_equals_the_per_pixel_one():
    rng = np.random.default_rng(3)
    for points in _point_sets(rng, 80):  # the per-pixel reference is slow on large hulls; every object's kept
        hull = hand_shape.convex_hull(points)
        if len(hull) < 3:
            continue
        xs = np.arange(np.floor(points[:, 0].min()) - 2, np.ceil(points[:, 0].max()) + 3) + 0.5
        ys = np.arange(np.floor(points[:, 1].min()) - 2, np.ceil(points[:, 1].max()) + 3) + 0.5
        np.testing.assert_array_equal(hand_shape.hull_depth(xs, ys, hull), _per_pixel_depth(xs, ys, hull))
        np.testing.assert_array_equal(hand_shape.hull_depth(xs, ys, hull[::-1]), _per_pixel_depth(xs, ys, hull[::-1]))


def _hand(palm=REST_PALM, joints=REST_JOINTS, hand: str = "right"):
    palm = np.asarray(palm, dtype=np.float32)
    joints = np.asarray(joints, dtype=np.float32)
    jp, kp = forward_kinematics(palm[None].astype(np.float64), joints[None].astype(np.float64), hand)
    return palm, jp[0].astype(np.float32), kp[0].astype(np.float32)


@pytest.mark.parametrize("palm", [REST_PALM, (0.5, 1.4, 3.0, 0.0, 0.0, 0.3)])
def test_windowed_hand_mask_is_the_full_mask_cut_to_the_window(palm):
    state = _hand(palm, np.full(15, 0.4))
    full = hand_mask(*state, RES, RES)
    assert full.any()
    shape = HandShape.of(*state, RES, RES)
    np.testing.assert_array_equal(shape.mask(RES, RES), full)
    for window in [(0, RES, 0, RES), (100, 224, 60, 160), (150, 200, 0, 40), (0, 10, 0, 10)]:
        r0, r1, c0, c1 = window
        cut = np.zeros_like(full)
        cut[r0:r1, c0:c1] = full[r0:r1, c0:c1]
        np.testing.assert_array_equal(hand_mask(*state, RES, RES, window=window), cut)


def test_cropped_template_matching_equals_full_frame_matching():
    rng = np.random.default_rng(5)
    category = OBJECTS["paper_roll"]
    tpl = template(category, category.nominal_size, np.array([0.4, 4.0]), 0.5, RES, RES)
    r0, c0 = tpl.origin[0] - 30, tpl.origin[1] - 25
    blob = np.zeros((RES, RES), dtype=bool)
    background = np.zeros((RES, RES), dtype=bool)
    window = (slice(r0, r0 + 90), slice(c0, c0 + 80))
    blob[window] = rng.random((90, 80)) < 0.3
    background[window] = ~blob[window] & (rng.random((90, 80)) < 0.8)
    for reach in (3, 12):
        full = match_template(tpl, blob, background, reach)
        cropped = match_template(tpl, blob[window], background[window], reach, (r0, c0))
        np.testing.assert_array_equal(full[0], cropped[0])
        assert full[1] == cropped[1]


def test_cached_unprojection_is_the_cameras():
    pixels = np.random.default_rng(2).uniform(0, RES, (50, 2))
    for plane in (0.0, 0.21, 0.4):
        np.testing.assert_array_equal(camera_model.unproject(pixels, RES, RES, plane),
                                      unproject_to_plane(pixels, RES, RES, plane))
        np.testing.assert_array_equal(camera_model.unproject(pixels[7], RES, RES, plane),
                                      unproject_to_plane(pixels[7], RES, RES, plane))


def test_size_estimate_follows_each_new_sample():
    name = "tennis_ball"
    nominal = OBJECTS[name].nominal_size
    locator = ObjectLocator("Grasp the moving tennis ball.", RES)
    assert locator.size == nominal
    for k, xz in enumerate([(-1.0, 3.0), (1.5, 5.0), (0.0, 6.5)]):
        image, palm, joint_poses, keypoints, _ = _scene(name, xz, 0.0)
        assert locator.locate(image, palm, joint_poses, keypoints) is not None
        assert len(locator._size_samples) == k + 1
        expected = float(np.clip(np.median(locator._size_samples), 0.7 * nominal, 1.3 * nominal))
        assert locator.size == expected
