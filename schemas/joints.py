"""Names of the hand's degrees of freedom, in the order every array stores them
(``joint_angles``, the 15 joint columns of ``action``, keypoints)."""

from __future__ import annotations

FINGERS = ("thumb", "index", "middle", "ring", "little")
_JOINT_SUFFIXES = {"thumb": ("cmc", "mcp", "ip")}
#: The 15 flexion joints: thumb cmc/mcp/ip, then mcp/pip/dip of each other finger.
JOINT_NAMES = tuple(
    f"{finger}_{joint}" for finger in FINGERS for joint in _JOINT_SUFFIXES.get(finger, ("mcp", "pip", "dip"))
)
#: Keypoint names in keypoint order: five fingertips, then the wrist.
KEYPOINT_NAMES = tuple(f"{finger}_tip" for finger in FINGERS) + ("wrist",)
#: The palm pose's six components (position, then R = Rz(yaw) Ry(pitch) Rx(roll)).
PALM_POSE_NAMES = ("palm_x", "palm_y", "palm_z", "palm_roll", "palm_pitch", "palm_yaw")
#: The 18 action components: the palm position target, then the 15 joint targets.
ACTION_NAMES = PALM_POSE_NAMES[:3] + JOINT_NAMES
#: The object pose's seven components (position, then the quaternion x, y, z, w).
OBJECT_POSE_NAMES = ("object_x", "object_y", "object_z", "object_qx", "object_qy", "object_qz", "object_qw")
