"""The hand in the shard's MCAP: its named frames and the skeleton drawn between them.

Every frame's ``/tf`` message carries, after world->camera, world->object and
world->palm, one world->frame transform per entry of :data:`HAND_FRAMES`: the six
keypoints (``thumb_tip`` ... ``little_tip``, ``wrist``) then the fifteen finger joints
(``thumb_cmc`` ... ``little_dip``), named as in :mod:`schemas.joints`, each at its
``keypoints``/``joint_poses`` row of the frames table in Foxglove's axes.

``/hand/skeleton`` (``foxglove.SceneUpdate``) draws the hand's links: one entity
:data:`SKELETON_ENTITY` in ``world`` holding one ``LINE_LIST`` whose ``points`` are the
positions of :data:`HAND_FRAMES` in that order and whose ``indices`` are the pairs of
:data:`SKELETON_LINKS` (per finger wrist -> its three joints -> its tip, plus the
knuckle line across the fingers' first joints, as ``pipeline view`` draws it). Each
message replaces the entity, so the scene always shows the current frame's hand.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity

from catalog.tables.mcap_encode import fields, length_delimited
from schemas.joints import FINGERS, JOINT_NAMES, KEYPOINT_NAMES

SKELETON_TOPIC = "/hand/skeleton"
SKELETON_ENTITY = "hand"
#: The hand's frame ids in ``/tf`` order; also the order of the skeleton's points.
HAND_FRAMES: tuple[str, ...] = KEYPOINT_NAMES + JOINT_NAMES
_WRIST = HAND_FRAMES.index("wrist")


def _links() -> tuple[tuple[int, int], ...]:
    """Per finger wrist -> first, second, third joint -> tip; then the knuckle line."""
    links: list[tuple[int, int]] = []
    for f, finger in enumerate(FINGERS):
        chain = [_WRIST, *(len(KEYPOINT_NAMES) + 3 * f + j for j in range(3)), HAND_FRAMES.index(f"{finger}_tip")]
        links.extend(zip(chain[:-1], chain[1:]))
    knuckles = [len(KEYPOINT_NAMES) + 3 * f for f in range(len(FINGERS))]
    links.extend(zip(knuckles[:-1], knuckles[1:]))
    return tuple(links)


#: Index pairs into :data:`HAND_FRAMES`, one per drawn link (24).
SKELETON_LINKS: tuple[tuple[int, int], ...] = _links()
#: Line width in screen pixels (``scale_invariant``), so the hand reads at any zoom.
SKELETON_THICKNESS_PX = 3.0
SKELETON_RGBA = (1.0, 0.78, 0.55, 1.0)
_INDICES = [i for link in SKELETON_LINKS for i in link]


def in_hand_order(keypoints: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """(..., 6, k) keypoint rows and (..., 15, k) joint rows -> (..., 21, k) in :data:`HAND_FRAMES` order."""
    return np.concatenate([np.asarray(keypoints), np.asarray(joints)], axis=-2)


def _skeleton_parts(frame_id: str) -> tuple[bytes, bytes, bytes]:
    """The fields of the skeleton's entity and line that never change, serialised once:
    the entity's after its timestamp, the line's before its points and after them."""
    r, g, b, a = SKELETON_RGBA
    head = LinePrimitive(type=LinePrimitive.LINE_LIST, thickness=SKELETON_THICKNESS_PX, scale_invariant=True)
    head.pose.orientation.w = 1.0
    tail = LinePrimitive(color=Color(r=r, g=g, b=b, a=a), indices=_INDICES)
    return fields(SceneEntity(frame_id=frame_id, id=SKELETON_ENTITY)), fields(head), fields(tail)


class SkeletonEncoder:
    """``foxglove.SceneUpdate`` bytes of the hand entity at one instant, in ``frame_id``'s
    axes: one entity :data:`SKELETON_ENTITY` holding one ``LINE_LIST`` over the points."""

    def __init__(self, frame_id: str) -> None:
        self._entity, self._head, self._tail = _skeleton_parts(frame_id)

    def encode(self, stamp: bytes, points: Sequence[bytes]) -> bytes:
        """``stamp``: the encoded ``Timestamp``; ``points``: the 21 points in :data:`HAND_FRAMES`
        order, each encoded as the line's field 5 (a ``Point3``)."""
        line = self._head + b"".join(points) + self._tail
        entity = length_delimited(1, stamp) + self._entity + length_delimited(11, line)
        return length_delimited(2, entity)
