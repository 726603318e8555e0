"""Arrow schemas of the shard tables: the columns of the data contract (``docs/concepts/data-contract.md``)."""

from __future__ import annotations

import pyarrow as pa

from schemas.runs import RUN_KEY

#: Fixed widths of the per-frame float arrays.
ARRAY_WIDTHS = {
    "object_pose": 7,
    "object_velocity": 3,
    "palm_pose": 6,
    "joint_angles": 15,
    "joint_poses": 90,
    "keypoints": 36,
    "action": 18,
}
#: Columns of per-frame float state, in table order (``action`` and the scalar distance follow).
STATE_COLUMNS = ("object_pose", "object_velocity", "palm_pose", "joint_angles", "joint_poses", "keypoints")


def _f32(width: int) -> pa.DataType:
    return pa.list_(pa.float32(), width)


FRAMES_SCHEMA = pa.schema(
    [
        pa.field("episode_index", pa.int64(), nullable=False),
        pa.field("frame_index", pa.int32(), nullable=False),
        pa.field("timestamp", pa.float64(), nullable=False),
        pa.field("phase", pa.string(), nullable=False),
        pa.field("image", pa.binary(), nullable=False),
        *[pa.field(name, _f32(ARRAY_WIDTHS[name]), nullable=False) for name in STATE_COLUMNS],
        pa.field("action", _f32(18), nullable=False),
        pa.field("fingertip_distance", pa.float32(), nullable=False),
    ]
)

#: The frames table of a build whose scenes may hold obstacles (``settings.obstacle_clearance``):
#: one more column, the hand's clearance from the nearest obstacle (units; <= 0 is contact;
#: +inf in an episode without obstacles).
OBSTACLE_CLEARANCE = "obstacle_clearance"
OBSTACLE_FRAMES_SCHEMA = pa.schema(list(FRAMES_SCHEMA) + [pa.field(OBSTACLE_CLEARANCE, pa.float32(), nullable=False)])

EPISODES_SCHEMA = pa.schema(
    [
        pa.field("episode_index", pa.int64(), nullable=False),
        pa.field("episode_id", pa.string(), nullable=False),
        pa.field("slice", pa.string(), nullable=False),
        pa.field("motion_type", pa.string(), nullable=False),
        pa.field("tokens", pa.string(), nullable=False),
        pa.field("object", pa.string(), nullable=False),
        pa.field("object_size", pa.float32(), nullable=False),
        pa.field("rolling", pa.bool_(), nullable=False),
        pa.field("hand", pa.string(), nullable=False),
        pa.field("rollout_format", pa.string(), nullable=False),
        pa.field("intercept_setting", pa.string(), nullable=False),
        pa.field("intercept_time_s", pa.float32(), nullable=False),
        pa.field("observe_frames", pa.int32(), nullable=False),
        pa.field("intercept_frame", pa.int32(), nullable=False),
        pa.field("num_frames", pa.int32(), nullable=False),
        pa.field("grasp_angles", _f32(15), nullable=False),
        pa.field("seed", pa.int64(), nullable=False),
        pa.field("spec_hash", pa.string(), nullable=False),
        pa.field("text", pa.string(), nullable=False),
        # The full spec as canonical JSON, so that a shard alone can be replayed.
        pa.field("spec", pa.string(), nullable=False),
    ]
)

#: Columns evaluated rollouts add to the episodes table.
ROLLOUT_FIELDS = [
    pa.field(RUN_KEY, pa.string(), nullable=False),
    pa.field("privileged", pa.bool_(), nullable=False),
    pa.field("status", pa.string(), nullable=False),
    pa.field("error", pa.string(), nullable=False),
]
ROLLOUT_EPISODES_SCHEMA = pa.schema(list(EPISODES_SCHEMA) + ROLLOUT_FIELDS)
