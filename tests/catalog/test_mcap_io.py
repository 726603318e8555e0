"""The MCAP file: one foxglove.CompressedImage per frame, decodable poses, computed times."""

import math
from collections import Counter

import numpy as np
import pytest

from catalog import mcap_io
from catalog.mcap_io import (
    IMAGE_SCHEMA,
    IMAGE_TOPIC,
    McapShardWriter,
    camera_calibration,
    camera_pose,
    euler_to_quaternion,
    iter_messages,
    log_time_ns,
    mcap_summary,
    read_episode_metadata,
    to_foxglove_position,
    to_foxglove_quaternion,
)
from catalog.shard import ShardWriter
from schemas.errors import ShardError
from schemas.frames import EpisodeFrames
from schemas.scene import CAMERA_TARGET

from .conftest import SETTINGS, make_episode


def _rot(q):
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


P = np.array([[1.0, 0, 0], [0, 0, 1], [0, 1, 0]])  # Dyana (x, y, z) -> Foxglove (x, z, y)


def _euler_matrix(roll, pitch, yaw):
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


@pytest.fixture(scope="module")
def shard(tmp_path_factory):
    root = tmp_path_factory.mktemp("mcap")
    with ShardWriter(root, 4, 7, SETTINGS) as writer:
        for i in range(4, 7):
            writer.add_episode(*make_episode(i))
    return root / writer.record.files["mcap"].path


def test_axes_conversion_is_the_reflected_rotation():
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q)
        assert np.allclose(_rot(to_foxglove_quaternion(q)), P @ _rot(q) @ P)
        rpy = rng.uniform(-3, 3, 3)
        assert np.allclose(_rot(euler_to_quaternion(rpy)), _euler_matrix(*rpy))
    assert np.array_equal(to_foxglove_position([1.0, 2.0, 3.0]), [1.0, 3.0, 2.0])


def test_log_time_layout():
    assert log_time_ns(0, 0) == 0
    assert log_time_ns(3, 7) == 300_000_000_000 + 350_000_000
    assert mcap_io.max_frames(20) == 2000
    with pytest.raises(ShardError, match="fps"):
        log_time_ns(0, 1, fps=7)


def test_one_compressed_image_per_frame(shard):
    summary = mcap_summary(shard)
    episodes = [make_episode(i) for i in range(4, 7)]
    total = sum(f.num_frames for _, f, _ in episodes)
    assert summary.library == "dyana/0.1.0" and summary.profile == ""
    assert summary.topics[IMAGE_TOPIC] == (IMAGE_SCHEMA, total)
    assert summary.count(IMAGE_SCHEMA) == total
    images = [m for m in iter_messages(shard) if m.schema == IMAGE_SCHEMA]
    assert len(images) == total
    expected = [(i, f, img) for i, (_, frames, imgs) in zip(range(4, 7), episodes) for f, img in enumerate(imgs)]
    for message, (episode, frame, image) in zip(images, expected):
        assert message.topic == IMAGE_TOPIC
        assert message.message.data == image and message.message.format == "jpeg"
        assert message.message.frame_id == "camera"
        t = log_time_ns(episode, frame)
        assert message.log_time_ns == message.publish_time_ns == t and message.sequence == frame
        assert message.message.timestamp.seconds * 10**9 + message.message.timestamp.nanos == t
    counts = Counter(m.topic for m in iter_messages(shard, decode=False))
    assert set(counts.values()) == {total} and len(counts) == len(mcap_io.CHANNELS)


def test_poses_decode_to_the_frames(shard):
    _, frames, _ = make_episode(5)
    start = log_time_ns(5, 0)
    by_topic = {}
    for m in iter_messages(shard, ["/object/pose", "/hand/palm", "/hand/keypoints", "/hand/joints", "/tf"]):
        if start <= m.log_time_ns < start + frames.num_frames * 50_000_000:
            by_topic.setdefault(m.topic, []).append(m.message)
    assert {len(v) for v in by_topic.values()} == {frames.num_frames}
    f = 3
    obj = by_topic["/object/pose"][f]
    assert obj.frame_id == "world"
    pos = [obj.pose.position.x, obj.pose.position.y, obj.pose.position.z]
    assert np.allclose(pos, to_foxglove_position(frames.object_pose[f, :3]))
    quat = [obj.pose.orientation.x, obj.pose.orientation.y, obj.pose.orientation.z, obj.pose.orientation.w]
    assert np.allclose(_rot(quat), P @ _rot(frames.object_pose[f, 3:].astype(np.float64)) @ P, atol=1e-6)
    palm = by_topic["/hand/palm"][f].pose
    rpy = frames.palm_pose[f, 3:].astype(np.float64)
    palm_q = [palm.orientation.x, palm.orientation.y, palm.orientation.z, palm.orientation.w]
    assert np.allclose(_rot(palm_q), P @ _euler_matrix(*rpy) @ P, atol=1e-6)
    keypoints = by_topic["/hand/keypoints"][f]
    assert len(keypoints.poses) == 6
    wrist = keypoints.poses[5].position
    assert np.allclose([wrist.x, wrist.y, wrist.z], to_foxglove_position(frames.keypoints[f].reshape(6, 6)[5, :3]))
    assert len(by_topic["/hand/joints"][f].poses) == 15
    tf = by_topic["/tf"][f].transforms
    assert [(t.parent_frame_id, t.child_frame_id) for t in tf] == [
        ("world", "camera"), ("world", "object"), ("world", "palm")
    ]
    palm_tf = [tf[2].translation.x, tf[2].translation.y, tf[2].translation.z]
    assert np.allclose(palm_tf, to_foxglove_position(frames.palm_pose[f, :3]))


def test_camera_calibration_matches_the_renderers_projection():
    """The optical frame and intrinsics project world points where generators.camera does."""
    from generators.camera import project

    size = 64
    calib = camera_calibration(size, size)
    eye, q = camera_pose()
    rot = _rot(q)  # camera -> Foxglove world
    points = np.array([CAMERA_TARGET, [2.0, 0.5, 3.0], [-3.0, 0.0, 6.0]])
    cam = (to_foxglove_position(points) - eye) @ rot
    k = np.array(calib["K"]).reshape(3, 3)
    uv = (cam @ k.T)[:, :2] / cam[:, 2:3]
    expected, depth = project(points, size, size)
    assert np.all(depth > 0)
    assert np.allclose(uv, expected, atol=1e-6)


def test_episode_metadata_holds_the_spec(shard):
    records = read_episode_metadata(shard)
    assert [r["episode_index"] for r in records] == ["4", "5", "6"]
    spec, _, _ = make_episode(6)
    assert records[2]["spec"] == spec.to_json() and records[2]["episode_id"] == spec.episode_id
    assert records[2]["start_time_ns"] == str(log_time_ns(6, 0))


def test_too_long_episode_is_refused(tmp_path):
    n = mcap_io.max_frames(20) + 1
    zeros = {k: np.zeros((n, w), np.float32) for k, w in [("object_pose", 7), ("object_velocity", 3), ("palm_pose", 6),
             ("joint_angles", 15), ("joint_poses", 90), ("keypoints", 36), ("action", 18)]}
    frames = EpisodeFrames(phase=np.zeros(n, np.int8), fingertip_distance=np.zeros(n, np.float32),
                           palm_distance=np.zeros(n, np.float32), grasp_angles=np.zeros(15, np.float32), **zeros)
    with open(tmp_path / "x.mcap", "wb") as stream:
        writer = McapShardWriter(stream, first_episode=0, end_episode=1, settings=SETTINGS)
        with pytest.raises(ShardError, match="exceed the MCAP limit of 2000"):
            writer.add_episode(0, frames, [b"\xff\xd8\xff"] * n, {})
