"""The splayed hand's grasp configuration (datasets up to 4.x; the opposed designs':
tests/generators/test_grasp_design.py): limits, sizing, symmetry, contact."""

from __future__ import annotations

import numpy as np
import pytest

from generators.contact import signed_distance_local
from generators.grasp import (
    SPLAYED,
    SYNERGY_END,
    _finger_clearance,
    grasp_angles,
    lowest_fingertip_offset,
)
from generators.hand import FINGER_RADII, JOINT_LOWER, JOINT_UPPER, SPLAYED_THUMB, fingertip_positions
from schemas.errors import SpecError
from schemas.objects import OBJECTS
from schemas.scene import PALM_HOVER

FACTORS = np.linspace(0.7, 1.3, 7)


@pytest.mark.parametrize("name", sorted(OBJECTS))
def test_within_limits_and_bigger_objects_flex_less(name):
    cat = OBJECTS[name]
    previous = None
    for factor in FACTORS:
        g = grasp_angles(name, cat.nominal_size * factor, "right", SPLAYED)
        assert g.shape == (15,)
        assert np.all(g >= JOINT_LOWER) and np.all(g <= JOINT_UPPER)
        closure = g.reshape(5, 3)[:, 0] / SYNERGY_END[:, 0]
        assert np.all(closure > 0.0)
        if previous is not None:
            assert np.all(g <= previous + 1e-9), (name, factor)
        previous = g
    small = grasp_angles(name, cat.nominal_size * FACTORS[0], "right", SPLAYED)
    large = grasp_angles(name, cat.nominal_size * FACTORS[-1], "right", SPLAYED)
    assert large.sum() < small.sum()


@pytest.mark.parametrize("name", sorted(OBJECTS))
def test_both_hands_grasp_alike(name):
    size = OBJECTS[name].nominal_size
    np.testing.assert_allclose(grasp_angles(name, size, "left", SPLAYED), grasp_angles(name, size, "right", SPLAYED), atol=1e-9)


@pytest.mark.parametrize("name", sorted(OBJECTS))
def test_fingers_touch_without_penetrating(name):
    """At the canonical placement no finger capsule goes into the object and the closest
    fingertip is within a finger's thickness of the surface."""
    cat = OBJECTS[name]
    size = cat.nominal_size
    g = grasp_angles(name, size, "right", SPLAYED)
    top = 2.0 * cat.half_height(size)
    palm = np.array([0.0, top + PALM_HOVER, 0.0, 0.0, 0.0, 0.0])
    closure = g.reshape(5, 3)[:, 0] / SYNERGY_END[:, 0]
    for f in range(5):
        assert _finger_clearance(palm, np.array([closure[f]]), name, size, "right", SPLAYED)[0, f] >= -1e-3
    tips = fingertip_positions(palm[None], g[None], "right", SPLAYED_THUMB)[0] - np.array([0.0, cat.half_height(size), 0.0])
    axis = 0 if cat.lying else 1
    dist = np.abs(signed_distance_local(tips, cat.shape, cat.scaled_dims(size), axis))
    assert dist.min() <= FINGER_RADII.max() + 0.01


def test_fingers_stay_above_the_table():
    for name, cat in OBJECTS.items():
        size = cat.nominal_size * 0.85
        assert 2.0 * cat.half_height(size) + PALM_HOVER + lowest_fingertip_offset(name, size, "right", SPLAYED) > 0.0


def test_deterministic_and_validated():
    a = grasp_angles("mug", 0.84, "right", SPLAYED)
    a[0] = 99.0  # callers get their own copy
    np.testing.assert_array_equal(grasp_angles("mug", 0.84, "right", SPLAYED), grasp_angles("mug", 0.84, "right", SPLAYED))
    assert grasp_angles("mug", 0.84, "right", SPLAYED)[0] != 99.0
    with pytest.raises(SpecError, match="size"):
        grasp_angles("mug", -1.0, "right", SPLAYED)
    with pytest.raises(SpecError, match="unknown object"):
        grasp_angles("anvil", 1.0, "right", SPLAYED)
