"""The MCAP messages encoded directly (catalog.tables.mcap_encode) are the protobuf runtime's
bytes: every per-frame message of a written episode equals the message built field by
field and serialised deterministically, zeros and negative zeros included."""

import struct
from dataclasses import replace

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from catalog.tables.mcap_encode import doubles, length_delimited, rows, timestamp, varint
from catalog.tables.mcap_hand import SKELETON_ENTITY, SKELETON_LINKS, SKELETON_RGBA, SKELETON_THICKNESS_PX
from catalog.tables.mcap_layout import (
    TF_FRAMES,
    camera_calibration,
    camera_pose,
    frame_period_ns,
    to_foxglove_position,
    to_foxglove_quaternion,
)
from catalog.tables.mcap_reader import iter_messages
from catalog.tables.mcap_writer import McapShardWriter
from schemas.rotations import euler_to_quaternion

from .conftest import SETTINGS, make_episode


def _ser(message) -> bytes:
    return message.SerializeToString(deterministic=True)


@pytest.mark.parametrize("value", [0, 1, 127, 128, 300, 2**31, 999_999_999, 2**63 - 1])
def test_varint_and_timestamp_match_the_runtime(value):
    assert _ser(Vector3()) == b""
    seconds, nanos = divmod(value, 10**9)
    assert timestamp(value) == _ser(Timestamp(seconds=seconds, nanos=nanos))
    assert varint(value) == _ser(Timestamp(seconds=value))[1:] or value == 0


def test_doubles_leave_out_zero_bits_only():
    for values in ([0.0, 0.0, 0.0], [-0.0, 0.0, 1.5], [1.0, -2.0, 3.0], [float("inf"), 0.0, -0.0]):
        assert doubles(values) == _ser(Vector3(x=values[0], y=values[1], z=values[2]))
    assert length_delimited(3, b"x" * 200) == b"\x1a" + varint(200) + b"x" * 200


def test_rows_equal_each_row_encoded_alone():
    rng = np.random.default_rng(7)
    values = rng.standard_normal((400, 7))
    values[rng.random((400, 7)) < 0.2] = 0.0
    values[rng.random((400, 7)) < 0.05] = -0.0
    values[3] = 0.0

    def encode(row):
        return length_delimited(4, doubles(row[:3])) + length_delimited(5, doubles(row[3:]))

    assert rows(values, encode) == [encode(row) for row in values.tolist()]
    with pytest.raises(ValueError, match="exactly once"):
        rows(values, lambda row: doubles(row) + doubles(row))


# The messages as the writer built them with the runtime before it encoded them directly.
def _pose(position, quaternion) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = position
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = quaternion
    return pose


def _reference(stamp: Timestamp, image: bytes, pos: list, rot: list) -> list[bytes]:
    tf = FrameTransforms()
    for child, (x, y, z), (qx, qy, qz, qw) in zip(TF_FRAMES, pos, rot):
        transform = tf.transforms.add(parent_frame_id="world", child_frame_id=child)
        transform.timestamp.CopyFrom(stamp)
        transform.translation.x, transform.translation.y, transform.translation.z = x, y, z
        transform.rotation.x, transform.rotation.y, transform.rotation.z, transform.rotation.w = qx, qy, qz, qw

    def poses(part: slice) -> PosesInFrame:
        out = PosesInFrame(timestamp=stamp, frame_id="world")
        for position, quaternion in zip(pos[part], rot[part]):
            out.poses.add().CopyFrom(_pose(position, quaternion))
        return out

    skeleton = SceneUpdate()
    entity = skeleton.entities.add(frame_id="world", id=SKELETON_ENTITY)
    entity.timestamp.CopyFrom(stamp)
    r, g, b, a = SKELETON_RGBA
    line = entity.lines.add(type=LinePrimitive.LINE_LIST, thickness=SKELETON_THICKNESS_PX, scale_invariant=True,
                            color=Color(r=r, g=g, b=b, a=a), indices=[i for link in SKELETON_LINKS for i in link])
    line.pose.orientation.w = 1.0
    for x, y, z in pos[3:]:
        line.points.add(x=x, y=y, z=z)
    return [_ser(message) for message in (
        CompressedImage(timestamp=stamp, frame_id="camera", data=image, format="jpeg"),
        CameraCalibration(timestamp=stamp, frame_id="camera", **camera_calibration(SETTINGS["resolution"],
                                                                                   SETTINGS["resolution"])),
        tf,
        PoseInFrame(timestamp=stamp, frame_id="world", pose=_pose(pos[1], rot[1])),
        PoseInFrame(timestamp=stamp, frame_id="world", pose=_pose(pos[2], rot[2])),
        poses(slice(3, 9)),
        poses(slice(9, 24)),
        skeleton,
    )]


def _world_frames(frames) -> tuple[list, list]:
    """Per frame, the 24 /tf frames' positions and quaternions in Foxglove's axes."""
    n = frames.num_frames

    def six_dof(values):
        values = np.asarray(values, dtype=np.float64)
        return to_foxglove_position(values[..., :3]), to_foxglove_quaternion(euler_to_quaternion(values[..., 3:]))

    object_pose = np.asarray(frames.object_pose, dtype=np.float64)
    palm_pos, palm_rot = six_dof(frames.palm_pose)
    key_pos, key_rot = six_dof(np.asarray(frames.keypoints).reshape(n, 6, 6))
    joint_pos, joint_rot = six_dof(np.asarray(frames.joint_poses).reshape(n, 15, 6))
    camera_pos, camera_rot = camera_pose()
    pos = np.concatenate([np.broadcast_to(camera_pos, (n, 1, 3)), to_foxglove_position(object_pose[:, None, :3]),
                          palm_pos[:, None], key_pos, joint_pos], axis=1)
    rot = np.concatenate([np.broadcast_to(camera_rot, (n, 1, 4)), to_foxglove_quaternion(object_pose[:, None, 3:]),
                          palm_rot[:, None], key_rot, joint_rot], axis=1)
    return pos.tolist(), rot.tolist()


def test_written_messages_equal_the_runtime_serialisation(tmp_path):
    spec, frames, images = make_episode(0)
    # Zeros and negative zeros where the layout leaves a field out or keeps it.
    object_pose = frames.object_pose.copy()
    object_pose[1, :3] = 0.0
    object_pose[2, 0] = -0.0
    keypoints = frames.keypoints.copy()
    keypoints[:, 3:6] = 0.0
    joint_poses = frames.joint_poses.copy()
    joint_poses[4] = 0.0
    frames = replace(frames, object_pose=object_pose, keypoints=keypoints, joint_poses=joint_poses)
    path = tmp_path / "one.mcap"
    with open(path, "wb") as stream:
        writer = McapShardWriter(stream, first_episode=0, end_episode=1, settings=SETTINGS)
        writer.add_episode(0, frames, images, {"episode_id": spec.episode_id})
        writer.close()
    by_frame: dict[int, list[bytes]] = {}
    for message in iter_messages(path, decode=False):
        by_frame.setdefault(message.log_time_ns, []).append(message.message)
    assert len(by_frame) == frames.num_frames
    n = frames.num_frames
    pos, rot = _world_frames(frames)
    period = frame_period_ns(SETTINGS["fps"])
    for f in range(n):
        t = f * period
        stamp = Timestamp(seconds=t // 10**9, nanos=t % 10**9)
        assert by_frame[t] == _reference(stamp, images[f], pos[f], rot[f]), f"frame {f}"
    decoded = {m.log_time_ns: m for m in iter_messages(path, topics=["/tf"])}
    # The zeros reached the file as zeros (left out), the negative zero as written.
    first = decoded[period].message.transforms[1].translation
    assert (first.x, first.y, first.z) == (0.0, 0.0, 0.0)
    assert struct.pack("<d", decoded[2 * period].message.transforms[1].translation.x) == struct.pack("<d", -0.0)
