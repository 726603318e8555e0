"""The MCAP file: one foxglove.CompressedImage per frame, decodable poses and hand frames,
continuous computed times, one named metadata record per episode."""

import contextlib
import hashlib
import json
import math
import os
import shutil
import subprocess
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from catalog.tables import mcap_layout
from catalog.tables.mcap_hand import HAND_FRAMES, SKELETON_ENTITY, SKELETON_LINKS, SKELETON_TOPIC
from catalog.tables.mcap_layout import (
    IMAGE_SCHEMA,
    IMAGE_TOPIC,
    camera_calibration,
    camera_pose,
    episode_metadata_name,
    log_time_ns,
    to_foxglove_position,
    to_foxglove_quaternion,
)
from catalog.tables.mcap_reader import iter_messages, mcap_summary, read_episode_metadata, read_metadata, read_timeline
from catalog.tables.mcap_writer import McapShardWriter
from catalog.tables.parquet_io import column_to_numpy
from catalog.tables.shard import ShardWriter
from schemas.errors import ShardError
from schemas.frames import EpisodeFrames
from schemas.rotations import euler_to_quaternion
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


EPISODES = range(4, 7)
PERIOD_NS = 50_000_000


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """One shard of episodes 4-6: the writer's record and its folder."""
    root = tmp_path_factory.mktemp("mcap")
    with ShardWriter(root, EPISODES[0], EPISODES[-1] + 1, SETTINGS) as writer:
        for i in EPISODES:
            writer.add_episode(*make_episode(i))
    return root, writer.record


@pytest.fixture(scope="module")
def shard(written):
    root, record = written
    return root / record.files["mcap"].path


@pytest.fixture(scope="module")
def tables(written):
    """The shard's frames and episodes tables, as written beside the MCAP."""
    root, record = written
    return pq.read_table(root / record.files["frames"].path), pq.read_table(root / record.files["episodes"].path)


def _shard_position(episode, frame):
    """Frame ``frame`` of ``episode``'s position in the test shard (episodes 4-6 back to back)."""
    return sum(make_episode(i)[1].num_frames for i in EPISODES if i < episode) + frame


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
    assert log_time_ns(0) == 0
    assert log_time_ns(7) == 350_000_000
    assert log_time_ns(7, fps=10) == 700_000_000
    with pytest.raises(ShardError, match="fps"):
        log_time_ns(1, fps=7)
    assert episode_metadata_name(42) == "dyana.episode.000042"
    assert episode_metadata_name(1234567) == "dyana.episode.1234567"


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
        t = log_time_ns(_shard_position(episode, frame))
        assert message.log_time_ns == message.publish_time_ns == t and message.sequence == frame
        assert message.message.timestamp.seconds * 10**9 + message.message.timestamp.nanos == t
    counts = Counter(m.topic for m in iter_messages(shard, decode=False))
    assert set(counts.values()) == {total} and len(counts) == len(mcap_layout.CHANNELS)


def test_log_times_are_continuous_across_episodes(shard):
    """Every channel ticks exactly one frame period from the shard's first frame to its last,
    across episode boundaries, and the timeline maps each tick back to (episode, frame)."""
    times = {}
    for m in iter_messages(shard, decode=False):
        times.setdefault(m.topic, []).append(m.log_time_ns)
        assert m.publish_time_ns == m.log_time_ns
    total = sum(make_episode(i)[1].num_frames for i in EPISODES)
    assert set(times) == set(mcap_layout.CHANNELS)
    for topic, ts in times.items():
        assert ts[0] == 0, topic
        assert set(np.diff(ts).tolist()) == {PERIOD_NS}, topic
        assert len(ts) == total
    timeline = read_timeline(shard)
    assert timeline.period_ns == PERIOD_NS
    expected = [(i, f) for i in EPISODES for f in range(make_episode(i)[1].num_frames)]
    assert [timeline.locate(t) for t in times[IMAGE_TOPIC]] == expected
    for bad in (-PERIOD_NS, PERIOD_NS // 2, total * PERIOD_NS):
        with pytest.raises(ShardError, match="no frame"):
            timeline.locate(bad)


def test_poses_decode_to_the_frames(shard):
    _, frames, _ = make_episode(5)
    timeline = read_timeline(shard)
    by_topic = {}
    for m in iter_messages(shard, ["/object/pose", "/hand/palm", "/hand/keypoints", "/hand/joints", "/tf"]):
        if timeline.locate(m.log_time_ns)[0] == 5:
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
        ("world", "camera"), ("world", "object"), ("world", "palm"), *(("world", name) for name in HAND_FRAMES)
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


def _xyz(v):
    return [v.x, v.y, v.z]


def _expected_hand(frames):
    """The frames table's keypoints then joints per frame, in Foxglove's axes: positions
    (rows, 21, 3) and rotation matrices (rows, 21, 3, 3), computed independently of the writer."""
    keypoints = column_to_numpy(frames.column("keypoints")).astype(np.float64).reshape(-1, 6, 6)
    joints = column_to_numpy(frames.column("joint_poses")).astype(np.float64).reshape(-1, 15, 6)
    rows = np.concatenate([keypoints, joints], axis=1)
    rotation = P @ np.stack([[_euler_matrix(*rpy) for rpy in frame] for frame in rows[..., 3:]]) @ P
    return to_foxglove_position(rows[..., :3]), rotation


def test_hand_frames_and_skeleton_are_the_frames_tables_keypoints_and_joints(shard, tables):
    """/tf's keypoint and joint frames and /hand/skeleton's points are the frames table's
    keypoints and joint_poses in Foxglove's axes (positions swapped y/z, rotations reflected)."""
    frames, _ = tables
    position, rotation = _expected_hand(frames)
    tf = [m.message.transforms[3:] for m in iter_messages(shard, ["/tf"])]
    updates = [m.message for m in iter_messages(shard, [SKELETON_TOPIC])]
    assert len(tf) == len(updates) == frames.num_rows
    for k, (transforms, update) in enumerate(zip(tf, updates)):
        assert [t.child_frame_id for t in transforms] == list(HAND_FRAMES)
        assert np.allclose([_xyz(t.translation) for t in transforms], position[k], atol=1e-9)
        quats = [[t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w] for t in transforms]
        assert np.allclose([_rot(q) for q in quats], rotation[k], atol=1e-6)
        (entity,) = update.entities
        assert entity.id == SKELETON_ENTITY and entity.frame_id == "world" and not update.deletions
        stamp = transforms[0].timestamp
        assert (entity.timestamp.seconds, entity.timestamp.nanos) == (stamp.seconds, stamp.nanos)
        (line,) = entity.lines
        assert line.type == line.LINE_LIST and line.pose.orientation.w == 1.0
        assert np.allclose([_xyz(p) for p in line.points], position[k], atol=1e-9)
        assert list(line.indices) == [i for link in SKELETON_LINKS for i in link]


def test_skeleton_links_follow_each_finger_from_the_wrist():
    names = [(HAND_FRAMES[a], HAND_FRAMES[b]) for a, b in SKELETON_LINKS]
    assert names[:4] == [("wrist", "thumb_cmc"), ("thumb_cmc", "thumb_mcp"), ("thumb_mcp", "thumb_ip"),
                         ("thumb_ip", "thumb_tip")]
    assert names[-4:] == [("thumb_cmc", "index_mcp"), ("index_mcp", "middle_mcp"), ("middle_mcp", "ring_mcp"),
                          ("ring_mcp", "little_mcp")]
    assert len(names) == 24 and len(set(names)) == 24


def test_every_episode_has_its_own_named_metadata_record(shard, tables):
    records = read_metadata(shard)
    names = [name for name, _ in records]
    assert names == ["dyana.shard", "dyana.episode.000004", "dyana.episode.000005", "dyana.episode.000006"]
    assert "dyana.episode.NNNNNN" in records[0][1]["episode_metadata"]
    _, episodes = tables
    by_name = dict(records)
    start = 0
    for row in episodes.to_pylist():
        record = by_name[episode_metadata_name(row["episode_index"])]
        assert record["episode_index"] == str(row["episode_index"])
        assert record["episode_id"] == row["episode_id"] and record["spec"] == row["spec"]
        assert record["frames"] == str(row["num_frames"])
        assert record["start_time_ns"] == str(start * PERIOD_NS)
        assert record["end_time_ns"] == str((start + row["num_frames"] - 1) * PERIOD_NS)
        start += row["num_frames"]
    assert read_episode_metadata(shard) == [data for _, data in records[1:]]


def test_episode_metadata_holds_the_spec(shard):
    records = read_episode_metadata(shard)
    assert [r["episode_index"] for r in records] == ["4", "5", "6"]
    spec, _, _ = make_episode(6)
    assert records[2]["spec"] == spec.to_json() and records[2]["episode_id"] == spec.episode_id
    assert records[2]["start_time_ns"] == str(log_time_ns(_shard_position(6, 0)))


def test_long_episodes_are_written_back_to_back(tmp_path):
    """No per-episode time window: at 1 FPS an episode of 101 frames (longer than the former
    100 s per episode) is written, and the next starts one frame period after its last frame."""
    n, period = 101, 10**9
    zeros = {k: np.zeros((n, w), np.float32) for k, w in [("object_pose", 7), ("object_velocity", 3), ("palm_pose", 6),
             ("joint_angles", 15), ("joint_poses", 90), ("keypoints", 36), ("action", 18)]}
    frames = EpisodeFrames(phase=np.zeros(n, np.int8), fingertip_distance=np.zeros(n, np.float32),
                           palm_distance=np.zeros(n, np.float32), grasp_angles=np.zeros(15, np.float32), **zeros)
    path = tmp_path / "x.mcap"
    with open(path, "wb") as stream:
        writer = McapShardWriter(stream, first_episode=0, end_episode=2, settings=dict(SETTINGS, fps=1))
        writer.add_episode(0, frames, [b"\xff\xd8\xff"] * n, {})
        writer.add_episode(1, frames, [b"\xff\xd8\xff"] * n, {})
        writer.close()
    timeline = read_timeline(path)
    assert timeline.period_ns == period
    assert [(e.episode_index, e.start_ns, e.frames) for e in timeline.episodes] == [(0, 0, n), (1, n * period, n)]
    assert timeline.locate((n - 1) * period) == (0, n - 1) and timeline.locate(n * period) == (1, 0)
    times = [m.log_time_ns for m in iter_messages(path, [IMAGE_TOPIC], decode=False)]
    assert times == [k * period for k in range(2 * n)]


def test_files_of_the_former_layout_still_map_times_to_episodes(tmp_path):
    """Before: every episode record named ``dyana.episode``, episodes 100 s apart."""
    from mcap.writer import Writer

    path = tmp_path / "old.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="dyana/0.1.0")
        writer.add_metadata("dyana.shard", {"settings": json.dumps(SETTINGS)})
        for episode in (4, 5):
            writer.add_metadata("dyana.episode", {"episode_index": str(episode),
                                                  "start_time_ns": str(episode * 100 * 10**9)})
        writer.finish()
    assert [r["episode_index"] for r in read_episode_metadata(path)] == ["4", "5"]
    timeline = read_timeline(path)
    assert timeline.locate(400 * 10**9 + 3 * PERIOD_NS) == (4, 3)
    assert timeline.locate(500 * 10**9) == (5, 0)


JS_READER = Path(__file__).parent / "mcap_js"


@pytest.fixture(scope="module")
def node_modules(request, tmp_path_factory):
    """A folder with @mcap/core and protobufjs installed from the lock file (cached across
    runs in pytest's cache); skips without node and npm, or when npm cannot install them."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node and npm are not installed")
    lock = (JS_READER / "package-lock.json").read_bytes()
    name = f"mcap-js-{hashlib.sha256(lock).hexdigest()[:16]}"
    cache = getattr(request.config, "cache", None)
    parent = cache.mkdir("dyana") if cache is not None else tmp_path_factory.getbasetemp()
    target = parent / name
    if not (target / "node_modules" / "@mcap" / "core").is_dir():
        staging = Path(tmp_path_factory.mktemp("npm"))
        for file in ("package.json", "package-lock.json"):
            shutil.copy(JS_READER / file, staging / file)
        try:
            result = subprocess.run([npm, "ci", "--ignore-scripts", "--no-audit", "--no-fund", "--loglevel=error"],
                                    cwd=staging, capture_output=True, text=True, timeout=300)
        except subprocess.TimeoutExpired:
            pytest.skip("npm ci timed out (registry unreachable?)")
        if result.returncode != 0:
            pytest.skip(f"npm could not install @mcap/core: {result.stderr.strip()[-300:]}")
        with contextlib.suppress(OSError):
            os.replace(staging, target)
        if not target.is_dir():
            target = staging
    return target


def test_the_typescript_reader_sees_continuous_times_named_episodes_and_the_hand(node_modules, shard, tables):
    """@mcap/core (the MCAP project's TypeScript library) reads the shard through its indexes
    with CRCs checked; every episode's record is fetched by its own name, every channel ticks
    one frame period, and the decoded hand frames and skeleton are the frames table's."""
    result = subprocess.run([shutil.which("node"), str(JS_READER / "read_mcap.mjs"), str(node_modules), str(shard)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    seen = json.loads(result.stdout)
    assert seen["library"] == "dyana/0.1.0" and seen["profile"] == ""
    assert [(m["name"], m["data"]) for m in seen["metadata"]] == read_metadata(shard)
    frames, episodes = tables
    assert [m["name"] for m in seen["metadata"][1:]] == [episode_metadata_name(i) for i in EPISODES]
    assert [m["data"]["episode_id"] for m in seen["metadata"][1:]] == episodes.column("episode_id").to_pylist()
    assert set(seen["topics"]) == set(mcap_layout.CHANNELS)
    assert sum(len(t["log_times"]) for t in seen["topics"].values()) == int(seen["message_count"])
    for topic, times in seen["topics"].items():
        log = [int(t) for t in times["log_times"]]
        assert log == [int(t) for t in times["publish_times"]] == [k * PERIOD_NS for k in range(frames.num_rows)], topic
    position, rotation = _expected_hand(frames)
    assert len(seen["tf"]) == len(seen["skeleton"]) == frames.num_rows
    for k, (transforms, (entity,)) in enumerate(zip(seen["tf"], seen["skeleton"])):
        assert [(t["parent"], t["child"]) for t in transforms] == [("world", c) for c in mcap_layout.TF_FRAMES]
        hand = transforms[3:]
        assert {t["stamp"] for t in transforms} == {entity["stamp"]} == {str(k * PERIOD_NS)}
        assert np.allclose([t["translation"] for t in hand], position[k], atol=1e-9)
        assert np.allclose([_rot(t["rotation"]) for t in hand], rotation[k], atol=1e-6)
        assert (entity["id"], entity["frame_id"]) == (SKELETON_ENTITY, "world")
        (line,) = entity["lines"]
        assert line["type"] == 2  # LINE_LIST
        assert np.allclose(line["points"], position[k], atol=1e-9)
        assert line["indices"] == [i for link in SKELETON_LINKS for i in link]
