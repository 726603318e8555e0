"""Bad arguments to the generators raise DyanaErrors naming the thing, not numpy,
OpenCV or functools exceptions."""

import numpy as np
import pytest

from generators.contact import signed_distance_local
from generators.encode import decode_jpeg, encode_jpeg
from generators.grasp import grasp_angles, lowest_fingertip_offset
from generators.hand import forward_kinematics
from generators.motion import (
    arc_length,
    evaluate,
    motion_bounds,
    object_angular_velocity,
    object_pose,
)
from schemas.errors import ShardError, SpecError
from schemas.motion import HarmonicToken, LineToken, Motion, Track

LINE = Motion.of(LineToken((0.0, 3.0), 0.0, 1.0, 0.0, 5.0))


@pytest.mark.parametrize("times", ["abc", [object()], [1j]])
def test_non_numeric_times_are_spec_errors(times):
    with pytest.raises(SpecError, match="times"):
        evaluate(LINE, times)
    with pytest.raises(SpecError, match="times"):
        arc_length(LINE, times)


@pytest.mark.parametrize(
    "call",
    [
        lambda m: evaluate(m, [0.0]),
        lambda m: arc_length(m, [0.0]),
        lambda m: object_pose(m, "orange", 0.8, [0.0]),
        lambda m: object_angular_velocity(m, "orange", 0.8, [0.0]),
        lambda m: motion_bounds(m, 1.0),
    ],
)
def test_a_non_motion_is_a_spec_error(call):
    with pytest.raises(SpecError, match="not a Motion"):
        call(None)


@pytest.mark.parametrize("samples", ["many", 2.5, True, 1])
def test_motion_bounds_checks_samples(samples):
    sway = Track((HarmonicToken((0.0, 0.0), 0.0, 0.5, 1.0, 0.0, 1.0),), 1.0)
    with pytest.raises(SpecError, match="samples"):
        motion_bounds(Motion(LINE.base, (sway,)), 2.0, samples=samples)


def test_grasp_rejects_unhashable_arguments_with_spec_errors():
    with pytest.raises(SpecError, match="object"):
        grasp_angles(["orange"], 0.8, "right")
    with pytest.raises(SpecError, match="hand side"):
        grasp_angles("orange", 0.8, ["right"])
    with pytest.raises(SpecError, match="hand side"):
        lowest_fingertip_offset("orange", 0.8, {"right": 1})


def test_grasp_accepts_numpy_sizes():
    assert np.array_equal(grasp_angles("orange", np.float64(0.8), "right"), grasp_angles("orange", 0.8, "right"))
    assert np.array_equal(grasp_angles("orange", np.float32(0.75), "left"), grasp_angles("orange", 0.75, "left"))
    assert lowest_fingertip_offset("orange", np.float32(0.75), "right") == lowest_fingertip_offset("orange", 0.75, "right")


def test_forward_kinematics_rejects_batched_batches():
    with pytest.raises(SpecError, match="palm_pose"):
        forward_kinematics(np.zeros((2, 2, 6)), np.zeros((2, 2, 15)), "right")


def test_unknown_primitive_is_a_spec_error():
    with pytest.raises(SpecError, match="cone"):
        signed_distance_local(np.zeros(3), "cone", (1.0,))


@pytest.mark.parametrize("data", [b"", None, "text", encode_jpeg(np.zeros((16, 16, 3), np.uint8))[:20]])
def test_undecodable_images_are_shard_errors(data):
    with pytest.raises(ShardError):
        decode_jpeg(data)
