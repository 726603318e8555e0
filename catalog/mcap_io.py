"""The shard's MCAP file: Foxglove's well-known protobuf schemas, so Foxglove opens
it without configuration, written byte-for-byte reproducibly; and readers.

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
skeleton's points and links are defined in :mod:`catalog.mcap_hand`.

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
episode is at its record's ``start_time_ns + f * 10**9 // fps``; :func:`read_timeline`
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
apart; :func:`read_episode_metadata` and :func:`read_timeline` read both.

Pinned: the header ``library`` (``dyana/<code version>``) and empty ``profile``; no
compression (JPEG payloads dominate, and the bytes then do not depend on a zstd
build); chunk size :data:`CHUNK_SIZE`; all indexes, statistics, summary offsets and
repeated schemas/channels; summary and data-section CRCs; protobuf serialisation in
deterministic mode. The schema records are the ``FileDescriptorSet`` of the
installed ``foxglove-schemas-protobuf``, so the bytes depend on that package's
version (and on ``mcap``'s record layout), which the lock file pins.
"""

from __future__ import annotations

import bisect
import json
import math
import os
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, BinaryIO

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneEntityDeletion_pb2 import SceneEntityDeletion
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.reader import NonSeekingReader, make_reader
from mcap.well_known import MessageEncoding
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as _McapWriter
from mcap_protobuf.decoder import DecoderFactory
from mcap_protobuf.schema import register_schema

from catalog.hashing import canonical_json
from catalog.mcap_hand import HAND_FRAMES, SKELETON_TOPIC, in_hand_order, skeleton_update
from catalog.storage import open_binary
from schemas.errors import ShardError
from schemas.frames import EpisodeFrames
from schemas.joints import KEYPOINT_NAMES
from schemas.obstacles import Obstacle
from schemas.rotations import euler_to_quaternion, matrix_to_quaternion
from schemas.scene import CAMERA_EYE, CAMERA_FOV_DEG, CAMERA_TARGET
from schemas.versions import CODE_VERSION, FPS, SCHEMA_VERSION

LIBRARY = f"dyana/{CODE_VERSION}"
PROFILE = ""
CHUNK_SIZE = 4 * 1024 * 1024
SHARD_METADATA = "dyana.shard"
EPISODE_METADATA = "dyana.episode"
WORLD_FRAME = "world"
CAMERA_FRAME = "camera"
IMAGE_TOPIC = "/camera/image"
IMAGE_SCHEMA = "foxglove.CompressedImage"

#: Topic -> message class, in channel registration order.
CHANNELS: dict[str, type] = {
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
_KEYPOINTS = slice(3, 3 + len(KEYPOINT_NAMES))
_JOINTS = slice(_KEYPOINTS.stop, len(TF_FRAMES))
_HAND = slice(_KEYPOINTS.start, len(TF_FRAMES))
_IMAGE_MAGIC = {"jpeg": b"\xff\xd8\xff", "png": b"\x89PNG\r\n\x1a\n"}


# --- time and axes --------------------------------------------------------------------


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


# --- writing --------------------------------------------------------------------------


def _timestamp(ns: int) -> Timestamp:
    return Timestamp(seconds=ns // 10**9, nanos=ns % 10**9)


def _set_pose(pose: Pose, position: Sequence[float], quaternion: Sequence[float]) -> Pose:
    pose.position.x, pose.position.y, pose.position.z = position
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = quaternion
    return pose


def _pose(position: Sequence[float], quaternion: Sequence[float]) -> Pose:
    return _set_pose(Pose(), position, quaternion)


def _poses(stamp: Timestamp, positions: Sequence[Sequence[float]], quaternions: Sequence[Sequence[float]]) -> PosesInFrame:
    out = PosesInFrame(timestamp=stamp, frame_id=WORLD_FRAME)
    for position, quaternion in zip(positions, quaternions):
        _set_pose(out.poses.add(), position, quaternion)
    return out


def _transforms(
    stamp: Timestamp,
    children: Sequence[str],
    positions: Sequence[Sequence[float]],
    quaternions: Sequence[Sequence[float]],
) -> FrameTransforms:
    """world -> each child frame, at ``stamp``."""
    out = FrameTransforms()
    for child, (x, y, z), (qx, qy, qz, qw) in zip(children, positions, quaternions):
        transform = out.transforms.add(parent_frame_id=WORLD_FRAME, child_frame_id=child)
        transform.timestamp.CopyFrom(stamp)
        transform.translation.x, transform.translation.y, transform.translation.z = x, y, z
        transform.rotation.x, transform.rotation.y, transform.rotation.z, transform.rotation.w = qx, qy, qz, qw
    return out


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

    def _write(self, topic: str, message: Any, time_ns: int, sequence: int) -> None:
        self._writer.add_message(
            channel_id=self._channels[topic],
            log_time=time_ns,
            publish_time=time_ns,
            data=message.SerializeToString(deterministic=True),
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
                                 in_hand_order(key_pos, joint_pos)], axis=1).tolist()
        tf_rot = np.concatenate([np.broadcast_to(camera_rot, (n, 1, 4)), object_rot[:, None], palm_rot[:, None],
                                 in_hand_order(key_rot, joint_rot)], axis=1).tolist()
        for f in range(n):
            t = start + f * self._period
            stamp = _timestamp(t)
            pos, rot = tf_pos[f], tf_rot[f]
            self._write(
                IMAGE_TOPIC,
                CompressedImage(timestamp=stamp, frame_id=CAMERA_FRAME, data=bytes(images[f]), format=self._format),
                t,
                f,
            )
            if self._calibration is not None:
                self._write(
                    "/camera/calibration",
                    CameraCalibration(timestamp=stamp, frame_id=CAMERA_FRAME, **self._calibration),
                    t,
                    f,
                )
            self._write("/tf", _transforms(stamp, TF_FRAMES, pos, rot), t, f)
            self._write("/object/pose", PoseInFrame(timestamp=stamp, frame_id=WORLD_FRAME, pose=_pose(pos[1], rot[1])),
                        t, f)
            self._write("/hand/palm", PoseInFrame(timestamp=stamp, frame_id=WORLD_FRAME, pose=_pose(pos[2], rot[2])),
                        t, f)
            self._write("/hand/keypoints", _poses(stamp, pos[_KEYPOINTS], rot[_KEYPOINTS]), t, f)
            self._write("/hand/joints", _poses(stamp, pos[_JOINTS], rot[_JOINTS]), t, f)
            self._write(SKELETON_TOPIC, skeleton_update(stamp, WORLD_FRAME, pos[_HAND]), t, f)
            if self._obstacles:
                self._write(OBSTACLE_TOPIC, _obstacle_update(stamp, obstacles), t, f)
        self.frames += n

    def close(self) -> None:
        """Write the last chunk, the summary and the footer (the stream stays open)."""
        self._writer.finish()


# --- reading --------------------------------------------------------------------------


@dataclass(frozen=True)
class McapSummary:
    """What the summary section says: header, per-topic (schema, count), metadata count."""

    library: str
    profile: str
    message_count: int
    topics: Mapping[str, tuple[str, int]]
    metadata_count: int

    def count(self, schema_name: str) -> int:
        """Messages of ``schema_name`` over all topics."""
        return sum(n for name, n in self.topics.values() if name == schema_name)


@dataclass(frozen=True)
class McapMessage:
    topic: str
    schema: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    message: Any


def _fail(path: str | os.PathLike[str], exc: BaseException) -> ShardError:
    reason = f"{type(exc).__name__}: {exc}"
    return ShardError(f"{path}: not a readable MCAP file (truncated or corrupt): {reason}")


def _open(path: str | os.PathLike[str]) -> BinaryIO:
    try:
        return open_binary(path)
    except FileNotFoundError:
        raise ShardError(f"{path}: file is missing") from None
    except OSError as exc:
        raise ShardError(f"{path}: cannot open: {exc.strerror or exc}") from None


def mcap_summary(path: str | os.PathLike[str]) -> McapSummary:
    """Read the header and summary section (cheap: no chunk is decompressed)."""
    with _open(path) as stream:
        try:
            reader = make_reader(stream)
            header = reader.get_header()
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                raise ShardError(f"{os.fspath(path)}: MCAP file has no summary statistics")
            stats = summary.statistics
            topics = {}
            for channel_id, channel in sorted(summary.channels.items()):
                schema = summary.schemas.get(channel.schema_id)
                topics[channel.topic] = (schema.name if schema else "", stats.channel_message_counts.get(channel_id, 0))
        except ShardError:
            raise
        except Exception as exc:  # any parse failure of a damaged file
            raise _fail(path, exc) from None
    return McapSummary(header.library, header.profile, stats.message_count, topics, stats.metadata_count)


def iter_messages(
    path: str | os.PathLike[str], topics: Sequence[str] | None = None, decode: bool = True
) -> Iterator[McapMessage]:
    """Every message in file order, reading the whole file linearly and validating CRCs.

    With ``decode`` the protobuf payload is decoded, else ``message`` holds the raw bytes.
    A truncated or corrupt file raises ShardError naming it (after the intact messages).
    """
    wanted = None if topics is None else set(topics)
    decoders: dict[int, Any] = {}
    factory = DecoderFactory()
    with _open(path) as stream:
        try:
            reader = NonSeekingReader(stream, validate_crcs=True)
            for schema, channel, message in reader.iter_messages():
                if wanted is not None and channel.topic not in wanted:
                    continue
                payload: Any = message.data
                if decode:
                    if channel.schema_id not in decoders:
                        decoders[channel.schema_id] = factory.decoder_for(channel.message_encoding, schema)
                    decoder = decoders[channel.schema_id]
                    if decoder is None:
                        raise ShardError(f"{os.fspath(path)}: no protobuf decoder for topic {channel.topic!r}")
                    payload = decoder(message.data)
                yield McapMessage(
                    channel.topic,
                    schema.name if schema else "",
                    message.log_time,
                    message.publish_time,
                    message.sequence,
                    payload,
                )
        except ShardError:
            raise
        except Exception as exc:
            raise _fail(path, exc) from None


def count_messages(path: str | os.PathLike[str]) -> dict[tuple[str, str], int]:
    """(topic, schema) -> number of messages, counted by reading the whole file (CRCs checked)."""
    return dict(sorted(Counter((m.topic, m.schema) for m in iter_messages(path, decode=False)).items()))


def _is_episode_record(name: str) -> bool:
    """``dyana.episode.NNNNNN``, or the shared ``dyana.episode`` of older files."""
    prefix, _, index = name.rpartition(".")
    return name == EPISODE_METADATA or (prefix == EPISODE_METADATA and index.isdigit())


def read_metadata(path: str | os.PathLike[str]) -> list[tuple[str, dict[str, str]]]:
    """Every metadata record as (name, key/values), in file order (through the summary's
    metadata index)."""
    with _open(path) as stream:
        try:
            return [(m.name, dict(m.metadata)) for m in make_reader(stream).iter_metadata()]
        except Exception as exc:
            raise _fail(path, exc) from None


def read_episode_metadata(path: str | os.PathLike[str]) -> list[dict[str, str]]:
    """Every episode's metadata record, in file order (named ``dyana.episode.NNNNNN``,
    or ``dyana.episode`` in files written before episodes had names of their own)."""
    return [data for name, data in read_metadata(path) if _is_episode_record(name)]


@dataclass(frozen=True)
class EpisodeSpan:
    """Where one episode sits on its shard's clock."""

    episode_index: int
    start_ns: int
    frames: int | None


@dataclass(frozen=True)
class Timeline:
    """A shard's episodes on its clock, to map a log time back to (episode, frame)."""

    period_ns: int
    episodes: tuple[EpisodeSpan, ...]

    def locate(self, log_time_ns: int) -> tuple[int, int]:
        """``(episode_index, frame_index)`` of the frame logged at ``log_time_ns``."""
        starts = [e.start_ns for e in self.episodes]
        k = bisect.bisect_right(starts, log_time_ns) - 1
        if k >= 0:
            span = self.episodes[k]
            frame, rest = divmod(log_time_ns - span.start_ns, self.period_ns)
            if not rest and (span.frames is None or frame < span.frames):
                return span.episode_index, frame
        raise ShardError(f"log time {log_time_ns} ns is no frame of this shard's episodes")


def read_timeline(path: str | os.PathLike[str]) -> Timeline:
    """The shard's :class:`Timeline`, from its ``dyana.shard`` and episode metadata records."""
    records = read_metadata(path)
    shard = next((data for name, data in records if name == SHARD_METADATA), None)
    if shard is None:
        raise ShardError(f"{os.fspath(path)}: no {SHARD_METADATA} metadata record")
    try:
        period = frame_period_ns(int(json.loads(shard["settings"]).get("fps", FPS)))
        spans = tuple(
            EpisodeSpan(int(data["episode_index"]), int(data["start_time_ns"]),
                        int(data["frames"]) if "frames" in data else None)
            for name, data in records
            if _is_episode_record(name)
        )
    except (KeyError, ValueError, AttributeError) as exc:
        raise ShardError(f"{os.fspath(path)}: malformed metadata record: {type(exc).__name__}: {exc}") from None
    if any(a.start_ns >= b.start_ns for a, b in zip(spans, spans[1:])):
        raise ShardError(f"{os.fspath(path)}: episode start times do not increase")
    return Timeline(period, spans)


def check_mcap(path: str | os.PathLike[str], frames: int | None = None, full: bool = False) -> McapSummary:
    """Structural check: the summary is readable, written by us, with one image per frame.

    ``full`` also reads every chunk and checks the CRCs and that the counted images
    agree with the summary.
    """
    summary = mcap_summary(path)
    if not summary.library.startswith("dyana/"):
        raise ShardError(f"{os.fspath(path)}: MCAP written by {summary.library!r}, not by dyana")
    images = summary.count(IMAGE_SCHEMA)
    if frames is not None and images != frames:
        raise ShardError(f"{os.fspath(path)}: {images} {IMAGE_SCHEMA} messages for {frames} frames")
    if full:
        counted = sum(n for (_, schema), n in count_messages(path).items() if schema == IMAGE_SCHEMA)
        if counted != images:
            raise ShardError(f"{os.fspath(path)}: {counted} {IMAGE_SCHEMA} messages read, summary says {images}")
    return summary
