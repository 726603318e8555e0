"""How a Dyana folder maps onto a LeRobot dataset: features, file paths, metadata files.

Field mapping (one LeRobot frame per Dyana frame, same order; the names are
:mod:`catalog.loader.lerobot_names`'):

=================================  ======================================================
LeRobot feature                    Dyana source
=================================  ======================================================
``observation.images.ego``         ``image`` (the egocentric JPEG, decoded, re-encoded as
                                   video: H.264 or AV1, yuv420p)
``observation.state`` (21)         ``palm_pose`` (6: xyz, roll, pitch, yaw) then
                                   ``joint_angles`` (15)
``observation.environment_state``  ``object_pose`` (7: xyz, quaternion x, y, z, w); only with
                                   ``environment_state`` (``--environment-state``): it is
                                   privileged, and LeRobot policies take every
                                   ``observation.*`` feature as an input
``action`` (18)                    ``action`` (palm xyz target, 15 joint targets)
``timestamp``                      ``frame_index / fps`` (Dyana's own ``timestamp``)
``frame_index``                    ``frame_index``
``episode_index``                  the episode's position in the export (sources in the order
                                   given, each in its own order); ``dyana/source_hash`` and
                                   ``dyana/source_episode_index`` say where it came from
``index``                          the frame's position in the whole export
``task_index``                     the episode's ``text``, numbered in order of first use
=================================  ======================================================

What LeRobot has no slot for is kept per episode (``dyana/...`` columns of the v3.0
episodes table; the same keys in v2.1's ``meta/episodes.jsonl``): episode id, slice,
motion type, interception setting, object and its size, hand, rollout format, observe
and intercept frames, seed, the full spec (JSON), its hash and, for evaluated runs,
policy, status and error, and the provenance above. ``meta/dyana.json`` records each
source folder's slice hash and first exported episode, versions, the codec build and
every exported file's sha256.
"""

from __future__ import annotations

from typing import Any

from catalog.loader.lerobot_names import ACTION_KEY, ENV_KEY, IMAGE_KEY, INDEX_FEATURES, STATE_KEY
from schemas.joints import ACTION_NAMES, JOINT_NAMES, OBJECT_POSE_NAMES, PALM_POSE_NAMES

#: Export formats: name -> LeRobot codebase version.
FORMATS = {"lerobot": "v3.0", "lerobot-v2.1": "v2.1"}
#: The exported video's feature: the image's.
VIDEO_KEY = IMAGE_KEY
STATE_NAMES = PALM_POSE_NAMES + JOINT_NAMES
#: Each vector feature's element names.
VECTOR_NAMES = {
    STATE_KEY: STATE_NAMES,
    ENV_KEY: OBJECT_POSE_NAMES,
    ACTION_KEY: ACTION_NAMES,
}
PROVENANCE = ("source_hash", "source_episode_index")
#: Episode facts kept beside LeRobot's own (``dyana/<name>``), from the episodes table.
EPISODE_FACTS = (
    "episode_id", "slice", "motion_type", "intercept_setting", "object", "object_size", "hand", "rollout_format",
    "observe_frames", "intercept_frame", "seed", "spec_hash", "spec",
)
ROLLOUT_FACTS = ("policy", "privileged", "status", "error")
CHUNK_SIZE = 1000
V30_DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
V30_VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
V30_EPISODES_PATH = "meta/episodes/chunk-000/file-000.parquet"
V21_DATA_PATH = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
V21_VIDEO_PATH = "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
DYANA_META = "meta/dyana.json"


def vector_names(environment_state: bool) -> dict[str, tuple[str, ...]]:
    """The exported vectors (feature -> element names): the object's pose only if asked for."""
    return {key: names for key, names in VECTOR_NAMES.items() if environment_state or key != ENV_KEY}


def features(height: int, width: int, fps: int, codec: str, version: str, environment_state: bool) -> dict[str, Any]:
    """``info.json``'s ``features``: the video, the vectors and the index columns."""
    video_info = {
        "video.height": height,
        "video.width": width,
        "video.codec": codec,
        "video.pix_fmt": "yuv420p",
        "video.is_depth_map": False,
        "video.fps": fps,
        "video.channels": 3,
        "has_audio": False,
    }
    out: dict[str, Any] = {
        VIDEO_KEY: {
            "dtype": "video",
            "shape": [height, width, 3] if version == "v2.1" else [3, height, width],
            "names": ["height", "width", "channels"] if version == "v2.1" else ["channels", "height", "width"],
            "info": video_info,
        }
    }
    for key, names in vector_names(environment_state).items():
        out[key] = {"dtype": "float32", "shape": [len(names)], "names": list(names)}
    out["timestamp"] = {"dtype": "float32", "shape": [1], "names": None}
    for key in INDEX_FEATURES[1:]:
        out[key] = {"dtype": "int64", "shape": [1], "names": None}
    return out


def modality(version: str) -> dict[str, Any]:
    """GR00T's ``meta/modality.json``: which slices of the state and action vectors are
    which body part, the video key and the language annotation."""
    del version
    return {
        "state": {
            "palm_position": {"start": 0, "end": 3},
            "palm_orientation": {"start": 3, "end": 6, "rotation_type": "euler_angles_rpy"},
            "finger_joints": {"start": 6, "end": 21},
        },
        ACTION_KEY: {
            "palm_position": {"start": 0, "end": 3, "absolute": True},
            "finger_joints": {"start": 3, "end": 18, "absolute": True},
        },
        "video": {"ego": {"original_key": VIDEO_KEY}},
        "annotation": {"human.task_description": {"original_key": "task_index"}},
    }


def chunk_of(index: int) -> tuple[int, int]:
    """(chunk, position in chunk) of the ``index``-th file."""
    return index // CHUNK_SIZE, index % CHUNK_SIZE
