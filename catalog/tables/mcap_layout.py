"""The layout of a shard's MCAP file: channels, axes, clock and record names, shared by
:mod:`catalog.tables.mcap_writer` (which writes it byte-for-byte reproducibly) and
:mod:`catalog.tables.mcap_reader`. Foxglove's well-known protobuf schemas, so Foxglove opens
it without configuration.

Channels, registered once in this order at the start of every file:

=====================  ============================  ====================================
topic                  schema                        content (one message per frame)
=====================  ============================  ====================================
``/camera/image``      ``foxglove.CompressedImage``  the frame, ``format`` jpeg or png
``/camera/calibration`` ``foxglove.CameraCalibration`` pinhole intrinsics of the camera
``/tf``                ``foxglove.FrameTransforms``  world->camera, world->object, world->palm, then
                                                     world-> each keypoint and joint frame
``/object/pose``       ``foxglove.PoseInFrame``      the object's pose in ``world``
``/hand/palm``         ``foxglove.PoseInFrame``      the palm's pose in ``world``
``/hand/keypoints``    ``foxglove.PosesInFrame``     5 fingertips + wrist in ``world``
``/hand/joints``       ``foxglove.PosesInFrame``     the 15 finger joints in ``world``
``/hand/skeleton``     ``foxglove.SceneUpdate``      the hand's links as one line list in ``world``
``/scene/obstacles``   ``foxglove.SceneUpdate``      the obstacles as cubes in ``world``
=====================  ============================  ====================================

The hand's frame ids (``thumb_tip`` ... ``wrist``, ``thumb_cmc`` ... ``little_dip``) and the
skeleton's points and links are defined in :mod:`catalog.tables.mcap_hand`.

``/scene/obstacles`` exists only in shards of builds whose scenes may hold obstacles
(``settings.obstacle_clearance``); each of its messages first deletes every entity, then
adds one cube per obstacle of the episode (none in an episode without obstacles), in the
obstacle's category colour.

Axes: Dyana's world is X right, Y up, Z forward (left-handed); Foxglove's frames are
right-handed with Z up. The MCAP ``world`` frame therefore has ``x = Dyana x``
(right), ``y = Dyana z`` (forward), ``z = Dyana y`` (up): a reflection, under which
positions swap their y and z and a rotation quaternion ``(qx, qy, qz, qw)`` becomes
``(-qx, -qz, -qy, qw)``. Euler angles ``(roll, pitch, yaw)`` are read in pybullet's
convention ``R = Rz(yaw) Ry(pitch) Rx(roll)`` in Dyana's axes, then reflected the same
way. The ``camera`` frame is the optical frame (x right, y down, z forward in the image).

Time: a shard plays as one continuous clock. Its frames, episode after episode in
index order, are logged and published at ``n * (10**9 // fps)`` nanoseconds, ``n`` the
frame's position in the shard (0 for the first episode's first frame): an episode
starts one frame period after the previous episode's last frame, with no gap. The
epoch is 0 (Foxglove shows 1970-01-01 00:00:00 at the shard's first frame), so a log
time reads as the time into the shard; it depends only on the shard's own episodes,
never on the wall clock or on other shards. Every message's ``timestamp`` holds the
same value; ``sequence`` is the frame index within its episode. Frame ``f`` of an
episode is at its record's ``start_time_ns + f * 10**9 // fps``; :func:`catalog.tables.mcap_reader.read_timeline`
maps a log time back to ``(episode_index, frame_index)``.

Records beside the messages: a ``dyana.shard`` metadata record first (settings,
versions, episode range, axes, time layout) and, per episode, one metadata record named
``dyana.episode.NNNNNN`` (:func:`episode_metadata_name`: the episode index zero-padded to
six digits, e.g. ``dyana.episode.000042``), so every episode's record has a name of its
own in the summary's metadata index. It holds the
episode's ``episode_index``, ``episode_id``, canonical ``spec`` JSON, ``frames`` (logged
frames), ``start_time_ns`` and ``end_time_ns`` (its first and last frame's log time), and
for rollouts the ``policy``, ``status``, ``error`` (and ``privileged``). Files written
before this layout name every episode record ``dyana.episode`` and space episodes 100 s
apart; :func:`catalog.tables.mcap_reader.read_episode_metadata` and
:func:`~catalog.tables.mcap_reader.read_timeline` read both.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.message import Message

from catalog.tables.mcap_hand import HAND_FRAMES, SKELETON_TOPIC
from schemas.errors import ShardError
from schemas.rotations import matrix_to_quaternion
from schemas.scene import CAMERA_EYE, CAMERA_FOV_DEG, CAMERA_TARGET
from schemas.versions import FPS

SHARD_METADATA = "dyana.shard"
EPISODE_METADATA = "dyana.episode"
WORLD_FRAME = "world"
CAMERA_FRAME = "camera"
IMAGE_TOPIC = "/camera/image"
IMAGE_SCHEMA = "foxglove.CompressedImage"

#: Topic -> message class, in channel registration order.
CHANNELS: dict[str, type[Message]] = {
    IMAGE_TOPIC: CompressedImage,
    "/camera/calibration": CameraCalibration,
    "/tf": FrameTransforms,
    "/object/pose": PoseInFrame,
    "/hand/palm": PoseInFrame,
    "/hand/keypoints": PosesInFrame,
    "/hand/joints": PosesInFrame,
    SKELETON_TOPIC: SceneUpdate,
}
OBSTACLE_TOPIC = "/scene/obstacles"
#: The child frames of every ``/tf`` message, in order (all with parent ``world``).
TF_FRAMES: tuple[str, ...] = (CAMERA_FRAME, "object", "palm", *HAND_FRAMES)


def frame_period_ns(fps: int = FPS) -> int:
    if isinstance(fps, bool) or not isinstance(fps, int) or fps <= 0 or 10**9 % fps:
        raise ShardError(f"fps must be a positive integer dividing 10**9, got {fps!r}")
    return 10**9 // fps


def log_time_ns(shard_frame: int, fps: int = FPS) -> int:
    """Log time of the frame at position ``shard_frame`` of its shard: ``shard_frame * 10**9 // fps``."""
    return shard_frame * frame_period_ns(fps)


def episode_metadata_name(episode_index: int) -> str:
    """``dyana.episode.000042``: the name of one episode's metadata record."""
    return f"{EPISODE_METADATA}.{episode_index:06d}"


def to_foxglove_position(xyz: np.ndarray) -> np.ndarray:
    """Dyana (x, y, z) -> Foxglove world (x, z, y), for arrays (..., 3)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    return xyz[..., [0, 2, 1]]


def to_foxglove_quaternion(q: np.ndarray) -> np.ndarray:
    """A Dyana rotation (qx, qy, qz, qw) -> the same rotation in Foxglove's axes, (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    return np.stack([-q[..., 0], -q[..., 2], -q[..., 1], q[..., 3]], axis=-1)


def camera_pose() -> tuple[np.ndarray, np.ndarray]:
    """The camera optical frame in Foxglove's world: position (3,) and quaternion (4,)."""
    eye = to_foxglove_position(np.array(CAMERA_EYE))
    forward = to_foxglove_position(np.array(CAMERA_TARGET)) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return eye, matrix_to_quaternion(np.stack([right, down, forward], axis=1))


def camera_calibration(width: int, height: int) -> dict[str, Any]:
    """Pinhole intrinsics of the camera for an image of ``width`` x ``height`` (no distortion)."""
    f = (height / 2.0) / math.tan(math.radians(CAMERA_FOV_DEG) / 2.0)
    cx, cy = width / 2.0, height / 2.0
    return {
        "width": width,
        "height": height,
        "distortion_model": "plumb_bob",
        "D": [0.0] * 5,
        "K": [f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0],
        "R": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "P": [f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    }


def is_episode_record(name: str) -> bool:
    """``dyana.episode.NNNNNN``, or the shared ``dyana.episode`` of older files."""
    prefix, _, index = name.rpartition(".")
    return name == EPISODE_METADATA or (prefix == EPISODE_METADATA and index.isdigit())
