"""Writes a shard's MCAP file (:class:`McapShardWriter`) in the layout of
:mod:`catalog.tables.mcap_layout`, byte for byte reproducibly.

Pinned: the header ``library`` (``dyana/<code version>``) and empty ``profile``; no
compression (JPEG payloads dominate, and the bytes then do not depend on a zstd
build); chunk size :data:`CHUNK_SIZE`; all indexes, statistics, summary offsets and
repeated schemas/channels; summary and data-section CRCs; protobuf serialisation in
deterministic mode. The schema records are the ``FileDescriptorSet`` of the
installed ``foxglove-schemas-protobuf``, so the bytes depend on that package's
version (and on ``mcap``'s record layout). The per-frame messages are encoded directly
(:mod:`catalog.tables.mcap_encode`: the bytes the protobuf runtime gives, without building
~600 fields a frame in Python); the obstacles' cubes go through the runtime. The lock
``.ci/constraints.txt`` pins those versions (pyproject.toml only bounds them), and
``catalog verify`` reports a shard whose rebuild comes out different.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, BinaryIO

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneEntityDeletion_pb2 import SceneEntityDeletion
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.message import Message
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.well_known import MessageEncoding
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as _McapWriter
from mcap_protobuf.schema import register_schema

from catalog.store.hashing import canonical_json
from catalog.tables.mcap_encode import doubles, fields, length_delimited, rows, timestamp
from catalog.tables.mcap_hand import SKELETON_TOPIC, SkeletonEncoder, in_hand_order
from catalog.tables.mcap_layout import (
    CAMERA_FRAME,
    CHANNELS,
    EPISODE_METADATA,
    IMAGE_TOPIC,
    OBSTACLE_TOPIC,
    SHARD_METADATA,
    TF_FRAMES,
    WORLD_FRAME,
    camera_calibration,
    camera_pose,
    episode_metadata_name,
    frame_period_ns,
    log_time_ns,
    to_foxglove_position,
    to_foxglove_quaternion,
)
from schemas.errors import ShardError
from schemas.frames import EpisodeFrames
from schemas.joints import KEYPOINT_NAMES
from schemas.obstacles import Obstacle
from schemas.rotations import euler_to_quaternion
from schemas.versions import CODE_VERSION, FPS, SCHEMA_VERSION

LIBRARY = f"dyana/{CODE_VERSION}"
PROFILE = ""
CHUNK_SIZE = 4 * 1024 * 1024
_KEYPOINTS = slice(3, 3 + len(KEYPOINT_NAMES))
_JOINTS = slice(_KEYPOINTS.stop, len(TF_FRAMES))
_HAND = slice(_KEYPOINTS.start, len(TF_FRAMES))
#: A position (3,) or quaternion (4,): a list, or a row of a numpy array.
Vector = Sequence[float] | np.ndarray
_IMAGE_MAGIC = {"jpeg": b"\xff\xd8\xff", "png": b"\x89PNG\r\n\x1a\n"}


def _timestamp(ns: int) -> Timestamp:
    return Timestamp(seconds=ns // 10**9, nanos=ns % 10**9)


def _set_pose(pose: Pose, position: Vector, quaternion: Vector) -> Pose:
    pose.position.x, pose.position.y, pose.position.z = position
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = quaternion
    return pose


def _pose(position: Vector, quaternion: Vector) -> Pose:
    return _set_pose(Pose(), position, quaternion)


def _transform_fields(row: Sequence[float]) -> bytes:
    """A ``FrameTransform``'s translation (field 4) and rotation (field 5) from x y z qx qy qz qw."""
    return length_delimited(4, doubles(row[:3])) + length_delimited(5, doubles(row[3:]))


def _pose_field(row: Sequence[float]) -> bytes:
    """A ``foxglove.Pose`` (position, orientation) from x y z qx qy qz qw, as field 3 of
    ``PoseInFrame`` (``pose``) and ``PosesInFrame`` (``poses``)."""
    return length_delimited(3, length_delimited(1, doubles(row[:3])) + length_delimited(2, doubles(row[3:])))


def _point_field(row: Sequence[float]) -> bytes:
    """A ``foxglove.Point3`` as field 5 of ``LinePrimitive`` (``points``)."""
    return length_delimited(5, doubles(row))


def _obstacle_update(stamp: Timestamp, obstacles: Sequence[Obstacle]) -> SceneUpdate:
    """Delete every entity, then one cube per obstacle (Foxglove axes, its colour)."""
    entities = []
    for k, o in enumerate(obstacles):
        hx, hy, hz = o.half_extents
        centre = to_foxglove_position(np.array(o.position))
        rotation = to_foxglove_quaternion(np.array(o.quaternion))
        r, g, b, a = o.rgba
        cube = CubePrimitive(pose=_pose(centre, rotation), size=Vector3(x=2 * hx, y=2 * hz, z=2 * hy),
                             color=Color(r=r, g=g, b=b, a=a))
        entities.append(SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id=f"obstacle-{k}", metadata=[],
                                    cubes=[cube]))
    return SceneUpdate(deletions=[SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletion.ALL)],
                       entities=entities)


def _six_dof(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 6) Dyana x y z roll pitch yaw -> Foxglove positions and quaternions."""
    values = np.asarray(values, dtype=np.float64)
    return to_foxglove_position(values[..., :3]), to_foxglove_quaternion(euler_to_quaternion(values[..., 3:]))


class McapShardWriter:
    """Writes the MCAP file of one shard: :meth:`add_episode` in order, then :meth:`close`."""

    def __init__(
        self,
        stream: BinaryIO,
        *,
        first_episode: int,
        end_episode: int,
        settings: Mapping[str, Any],
        rollout: bool = False,
    ) -> None:
        self._fps = int(settings.get("fps", FPS))
        self._period = frame_period_ns(self._fps)
        self._format = str(settings.get("image_format", "jpeg"))
        if self._format not in _IMAGE_MAGIC:
            raise ShardError(f"image_format must be one of {sorted(_IMAGE_MAGIC)}, got {self._format!r}")
        resolution = settings.get("resolution")
        self._calibration = None
        if resolution is not None:
            if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution <= 0:
                raise ShardError(f"resolution must be a positive integer, got {resolution!r}")
            self._calibration = camera_calibration(resolution, resolution)
        self._camera = camera_pose()
        # The fields of each per-frame message that never change, serialised once (catalog.tables.mcap_encode).
        self._calibration_rest = None if self._calibration is None else fields(
            CameraCalibration(frame_id=CAMERA_FRAME, **self._calibration))
        self._image_tail = fields(CompressedImage(format=self._format, frame_id=CAMERA_FRAME))
        self._tf_heads = [fields(FrameTransform(parent_frame_id=WORLD_FRAME, child_frame_id=child)) for child in TF_FRAMES]
        self._world = fields(PoseInFrame(frame_id=WORLD_FRAME))
        self._skeleton = SkeletonEncoder(WORLD_FRAME)
        self._writer = _McapWriter(
            stream,
            chunk_size=CHUNK_SIZE,
            compression=CompressionType.NONE,
            index_types=IndexType.ALL,
            repeat_channels=True,
            repeat_schemas=True,
            use_chunking=True,
            use_statistics=True,
            use_summary_offsets=True,
            enable_crcs=True,
            enable_data_crcs=True,
        )
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._writer.add_metadata(
            SHARD_METADATA,
            {
                "schema_version": SCHEMA_VERSION,
                "code_version": CODE_VERSION,
                "episodes": f"[{first_episode}, {end_episode})",
                "rollout": "true" if rollout else "false",
                "settings": canonical_json(dict(settings)),
                "world_axes": "x = dyana x (right), y = dyana z (forward), z = dyana y (up)",
                "log_time": f"continuous: the n-th frame of the shard (from 0) at n * {self._period} ns; "
                "an episode's frame f at its start_time_ns + f * " + f"{self._period} ns",
                "episode_metadata": f"{EPISODE_METADATA}.NNNNNN, the episode index zero-padded to 6 digits",
            },
        )
        schema_ids: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._obstacles = bool(settings.get("obstacle_clearance", False))
        channels = dict(CHANNELS, **({OBSTACLE_TOPIC: SceneUpdate} if self._obstacles else {}))
        for topic, cls in channels.items():
            name = cls.DESCRIPTOR.full_name
            if name not in schema_ids:
                schema_ids[name] = register_schema(self._writer, cls)
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=schema_ids[name], metadata={}
            )
        self.frames = 0

    def _write(self, topic: str, message: Message, time_ns: int, sequence: int) -> None:
        self._write_bytes(topic, message.SerializeToString(deterministic=True), time_ns, sequence)

    def _write_bytes(self, topic: str, data: bytes, time_ns: int, sequence: int) -> None:
        self._writer.add_message(
            channel_id=self._channels[topic],
            log_time=time_ns,
            publish_time=time_ns,
            data=data,
            sequence=sequence,
        )

    def check_episode(self, episode_index: int, frames: EpisodeFrames, images: Sequence[bytes]) -> None:
        """Refuse an episode before anything is written: no frames, images missing or not of the format."""
        n = frames.num_frames
        if n < 1:
            raise ShardError(f"episode {episode_index}: no frames (an episode needs at least one)")
        if len(images) != n:
            raise ShardError(f"episode {episode_index}: {len(images)} images for {n} frames")
        magic = _IMAGE_MAGIC[self._format]
        for i, image in enumerate(images):
            if bytes(image[: len(magic)]) != magic:
                raise ShardError(f"episode {episode_index}: image of frame {i} is not a {self._format} image")

    def add_episode(
        self,
        episode_index: int,
        frames: EpisodeFrames,
        images: Sequence[bytes],
        metadata: Mapping[str, str],
        obstacles: Sequence[Obstacle] = (),
    ) -> None:
        """All messages of one episode, logged right after the previous episode's, plus its
        ``dyana.episode.NNNNNN`` metadata record."""
        self.check_episode(episode_index, frames, images)
        if obstacles and not self._obstacles:
            raise ShardError(f"episode {episode_index}: has obstacles but the shard's settings record none")
        n = frames.num_frames
        start = log_time_ns(self.frames, self._fps)
        record = {
            **metadata,
            "episode_index": str(episode_index),
            "frames": str(n),
            "start_time_ns": str(start),
            "end_time_ns": str(log_time_ns(self.frames + n - 1, self._fps)),
        }
        self._writer.add_metadata(episode_metadata_name(episode_index), {key: str(record[key]) for key in sorted(record)})

        object_pos = to_foxglove_position(np.asarray(frames.object_pose, dtype=np.float64)[:, :3])
        object_rot = to_foxglove_quaternion(np.asarray(frames.object_pose, dtype=np.float64)[:, 3:])
        palm_pos, palm_rot = _six_dof(frames.palm_pose)
        key_pos, key_rot = _six_dof(np.asarray(frames.keypoints).reshape(n, 6, 6))
        joint_pos, joint_rot = _six_dof(np.asarray(frames.joint_poses).reshape(n, 15, 6))
        camera_pos, camera_rot = self._camera
        tf_pos = np.concatenate([np.broadcast_to(camera_pos, (n, 1, 3)), object_pos[:, None], palm_pos[:, None],
                                 in_hand_order(key_pos, joint_pos)], axis=1)
        tf_rot = np.concatenate([np.broadcast_to(camera_rot, (n, 1, 4)), object_rot[:, None], palm_rot[:, None],
                                 in_hand_order(key_rot, joint_rot)], axis=1)
        tf = np.concatenate([tf_pos, tf_rot], axis=2)  # (n, frames, 7): one row per world->frame transform
        frames_per = tf.shape[1]
        # Per frame f and /tf frame k, at f * frames_per + k: that transform's translation and
        # rotation fields, the same as a foxglove.Pose field 3 (PoseInFrame, PosesInFrame), and
        # the position as a Point3 field 5 (the skeleton's LINE_LIST).
        transform = rows(tf.reshape(-1, 7), _transform_fields)
        pose = rows(tf.reshape(-1, 7), _pose_field)
        points = rows(tf_pos.reshape(-1, 3), _point_field)
        heads = self._tf_heads
        for f in range(n):
            t = start + f * self._period
            stamp = timestamp(t)
            stamped = length_delimited(1, stamp)
            row = f * frames_per
            self._write_bytes(IMAGE_TOPIC, stamped + length_delimited(2, bytes(images[f])) + self._image_tail, t, f)
            if self._calibration_rest is not None:
                self._write_bytes("/camera/calibration", stamped + self._calibration_rest, t, f)
            self._write_bytes("/tf", b"".join([length_delimited(1, stamped + heads[k] + transform[row + k])
                                               for k in range(frames_per)]), t, f)
            self._write_bytes("/object/pose", stamped + self._world + pose[row + 1], t, f)
            self._write_bytes("/hand/palm", stamped + self._world + pose[row + 2], t, f)
            self._write_bytes("/hand/keypoints", stamped + self._world + b"".join(
                pose[row + _KEYPOINTS.start : row + _KEYPOINTS.stop]), t, f)
            self._write_bytes("/hand/joints", stamped + self._world + b"".join(
                pose[row + _JOINTS.start : row + _JOINTS.stop]), t, f)
            self._write_bytes(SKELETON_TOPIC, self._skeleton.encode(stamp, points[row + _HAND.start : row + _HAND.stop]),
                              t, f)
            if self._obstacles:
                self._write(OBSTACLE_TOPIC, _obstacle_update(_timestamp(t), obstacles), t, f)
        self.frames += n

    def close(self) -> None:
        """Write the last chunk, the summary and the footer (the stream stays open)."""
        self._writer.finish()
