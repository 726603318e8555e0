"""The five-fingered hand: geometry, joint limits and vectorised forward kinematics.

Scene units (1 unit = 10 cm). The palm frame has its origin at the palm centre;
local +Z points along the fingers, local +Y out of the back of the hand, and the
palm faces local -Y. At the rest orientation (roll = pitch = yaw = 0) the palm
faces down (world -Y) with the fingers pointing forward (+Z, away from the camera).

Handedness: the world is X right, Y up, Z forward and the image shows +X on the
right, so a RIGHT hand, palm down and fingers forward, has its thumb toward -X.
The LEFT hand is its mirror image through the palm's YZ plane (thumb toward +X);
both hands take the same joint angles for the mirrored motion.

Each finger is a chain of three flexion joints rotating about the chain's local +X
axis; a positive angle curls the finger toward the palm side (local -Y). The thumb's
chain starts from a fixed, splayed root orientation. Where the chains root and point is a
:class:`HandGeometry`; the kinematics here take one and default to the dataset's,
:data:`DEFAULT_GEOMETRY`.

Poses are ``(x, y, z, roll, pitch, yaw)`` with ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``,
pybullet's ``getQuaternionFromEuler([roll, pitch, yaw])`` convention.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from schemas.errors import SpecError
from schemas.joints import FINGERS as FINGERS  # the names live in schemas (the data contract)
from schemas.joints import JOINT_NAMES as JOINT_NAMES
from schemas.joints import KEYPOINT_NAMES as KEYPOINT_NAMES
from schemas.names import shorten
from schemas.rotations import euler_to_matrix, matrix_to_euler
from schemas.scene import HANDS, PALM_REST

SIDES = HANDS

#: Palm box half extents (lateral, thickness, length) and the wrist point, palm frame.
PALM_HALF_EXTENTS = (0.45, 0.12, 0.50)
WRIST_OFFSET = (0.0, 0.0, -0.50)

#: Segment lengths (proximal, middle, distal); fingers 0.68-0.89 long.
SEGMENT_LENGTHS = np.array(
    [
        [0.40, 0.30, 0.26],
        [0.40, 0.23, 0.19],
        [0.43, 0.26, 0.20],
        [0.40, 0.25, 0.19],
        [0.32, 0.19, 0.17],
    ]
)
#: Finger thickness (radius of the capsules drawn and used for contact).
FINGER_RADII = np.array([0.095, 0.085, 0.085, 0.08, 0.07])

_FINGER_LIMITS = ((-0.35, 1.60), (0.0, 1.80), (0.0, 1.40))
_THUMB_LIMITS = ((-0.30, 1.20), (-0.20, 1.00), (-0.20, 1.30))
#: Joint limits (radians), shape (15,), in :data:`JOINT_NAMES` order.
JOINT_LOWER = np.array([lo for lims in (_THUMB_LIMITS,) + (_FINGER_LIMITS,) * 4 for lo, _ in lims])
JOINT_UPPER = np.array([hi for lims in (_THUMB_LIMITS,) + (_FINGER_LIMITS,) * 4 for _, hi in lims])
#: The rest configuration: open hand, straight fingers.
REST_JOINTS = np.zeros(15)
#: The palm's rest pose (x, y, z, roll, pitch, yaw), shared by both hands.
REST_PALM = np.array(PALM_REST, dtype=np.float64)

_MIRROR = np.diag([-1.0, 1.0, 1.0])

Vector = tuple[float, float, float]


def chain_rotation(along: Vector, curl: Vector) -> np.ndarray:
    """(3, 3) a chain root's rotation: its local +Z ``along`` (normalised), flexion (about
    local +X) swinging it toward ``curl``."""
    direction = np.array(along, dtype=np.float64)
    direction /= np.linalg.norm(direction)
    axis = np.cross(direction, np.array(curl, dtype=np.float64))
    axis /= np.linalg.norm(axis)
    return np.stack([axis, np.cross(direction, axis), direction], axis=1)


@dataclass(frozen=True)
class HandGeometry:
    """Where the right hand's five chains (thumb..little) start in the palm frame and which
    way each points; the left hand mirrors it. ``roots``: five (x, y, z) first-joint
    positions. ``directions``: per chain ``(along, curl)`` (:func:`chain_rotation`), or None
    for straight ahead (+Z) curling toward the palm side (-Y). Segment lengths, radii and
    joint limits are the same for every geometry."""

    name: str
    roots: tuple[Vector, ...]
    directions: tuple[tuple[Vector, Vector] | None, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SpecError(f"hand geometry name must be a non-empty string, got {shorten(repr(self.name))}")
        roots = np.asarray(self.roots, dtype=np.float64) if _numeric(self.roots) else None
        if roots is None or roots.shape != (5, 3) or not np.isfinite(roots).all():
            raise SpecError(f"hand geometry {self.name!r}: roots must be 5 finite (x, y, z), got {shorten(repr(self.roots))}")
        if not isinstance(self.directions, tuple) or len(self.directions) != 5:
            raise SpecError(f"hand geometry {self.name!r}: directions must be 5 entries, got {shorten(repr(self.directions))}")
        for d in self.directions:
            vectors = None if d is None else np.asarray(d, dtype=np.float64) if _numeric(d) else np.zeros(0)
            if vectors is not None and (vectors.shape != (2, 3) or not np.isfinite(vectors).all()
                                        or np.linalg.norm(np.cross(vectors[0], vectors[1])) < 1e-6):
                raise SpecError(f"hand geometry {self.name!r}: a direction must be None or two finite, "
                                f"non-parallel 3-vectors (along, curl), got {shorten(repr(d))}")

    def rotations(self) -> np.ndarray:
        """(5, 3, 3) the right hand's chain root rotations in the palm frame."""
        rots = np.repeat(np.eye(3)[None], 5, axis=0)
        for f, d in enumerate(self.directions):
            if d is not None:
                rots[f] = chain_rotation(d[0], d[1])
        return rots


def _numeric(value) -> bool:
    try:
        np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return True


_FINGER_ROOTS: tuple[Vector, ...] = ((-0.31, 0.0, 0.50), (-0.10, 0.0, 0.52), (0.11, 0.0, 0.50), (0.31, 0.0, 0.45))
#: The dataset's hand (4.x): the thumb roots at the palm's side (carpometacarpal joint),
#: points out and forward and flexes down and across under the palm, onto the side of an
#: object under the palm (it opposes no finger: see docs/concepts/grasp-hold.md).
SPLAYED_THUMB = HandGeometry(
    "splayed-thumb",
    ((-0.36, -0.04, -0.22), *_FINGER_ROOTS),
    (((-0.75, -0.20, 0.63), (0.45, -0.85, 0.30)), None, None, None, None),
)
#: The opposable thumb: it roots under the palm on its midline, 0.1 in from its rear edge,
#: points back in the palm's plane (so the resting hand hides little more than the palm) and
#: flexes down and forward, onto the back of an object under the palm, opposite the middle
#: and ring fingers (off the midline, at x = -0.1, a small ball slips out sideways).
OPPOSED_THUMB = HandGeometry(
    "opposed-thumb",
    ((0.0, -0.10, -0.40), *_FINGER_ROOTS),
    (((0.0, 0.0, -1.0), (0.0, -1.0, 0.0)), None, None, None, None),
)
#: Every hand geometry by name.
GEOMETRIES = MappingProxyType({g.name: g for g in (SPLAYED_THUMB, OPPOSED_THUMB)})
#: The dataset's hand (5.x; SPLAYED_THUMB up to 4.x), and (through
#: :data:`generators.grasp.DEFAULT_DESIGN`) its grasp: every function here and in the
#: modules that take a geometry or a design defaults to it.
DEFAULT_GEOMETRY = OPPOSED_THUMB


def hand_geometry(name: str) -> HandGeometry:
    """The registered hand geometry ``name``; a SpecError lists the known ones."""
    try:
        return GEOMETRIES[name]
    except (KeyError, TypeError):
        raise SpecError(f"unknown hand geometry {shorten(repr(name))} (expected one of {sorted(GEOMETRIES)})") from None


def root_rotations(side: str, geometry: HandGeometry = DEFAULT_GEOMETRY) -> np.ndarray:
    """(5, 3, 3) fixed rotations of each finger's chain root in the palm frame."""
    rots = geometry.rotations()
    if check_side(side) == "left":
        rots = _MIRROR @ rots @ _MIRROR
    return rots


def root_positions(side: str, geometry: HandGeometry = DEFAULT_GEOMETRY) -> np.ndarray:
    """(5, 3) positions of each finger's first joint in the palm frame."""
    roots = np.array(geometry.roots, dtype=np.float64)
    return roots @ _MIRROR if check_side(side) == "left" else roots


def check_side(side: str) -> str:
    """``side`` itself when it names a hand side, else a :class:`SpecError`."""
    if not isinstance(side, str) or side not in SIDES:
        raise SpecError(f"hand side must be one of {list(SIDES)}, got {shorten(repr(side))}")
    return side


@functools.lru_cache(maxsize=16)
def _frames(geometry: HandGeometry, side: str) -> tuple[np.ndarray, np.ndarray]:
    roots, rots = root_positions(side, geometry), root_rotations(side, geometry)
    roots.flags.writeable = rots.flags.writeable = False
    return roots, rots


def mirror_palm_pose(palm_pose: np.ndarray) -> np.ndarray:
    """The palm pose mirrored through the world's YZ plane (right <-> left)."""
    out = np.array(palm_pose, dtype=np.float64, copy=True)
    out[..., [0, 4, 5]] *= -1.0
    return out


def chain_frames(palm_pose: np.ndarray, joint_angles: np.ndarray, side: str,
                 geometry: HandGeometry = DEFAULT_GEOMETRY) -> tuple[np.ndarray, np.ndarray]:
    """World frames along the five chains.

    Returns positions (n, 5, 4, 3) and rotations (n, 5, 4, 3, 3): for each finger,
    its three joint frames (after the joint's rotation) and its fingertip frame
    (at the distal segment's end, oriented like the distal segment).
    """
    palm = np.atleast_2d(np.asarray(palm_pose, dtype=np.float64))
    q = np.atleast_2d(np.asarray(joint_angles, dtype=np.float64))
    if palm.ndim != 2 or q.ndim != 2 or palm.shape[-1] != 6 or q.shape[-1] != 15 or palm.shape[0] != q.shape[0]:
        raise SpecError(f"need palm_pose (n, 6) and joint_angles (n, 15), got {palm.shape} and {q.shape}")
    roots, root_rots = _frames(geometry, check_side(side))
    n = palm.shape[0]
    r_palm = euler_to_matrix(palm[:, 3:])
    pos = np.empty((n, 5, 4, 3))
    rot = np.empty((n, 5, 4, 3, 3))
    p = palm[:, None, :3] + (r_palm[:, None] @ roots[None, :, :, None])[..., 0]
    r = r_palm[:, None] @ root_rots[None]  # (n, 5, 3, 3)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    q = q.reshape(n, 5, 3)
    cos, sin = np.cos(q)[..., None], np.sin(q)[..., None]
    for k in range(3):
        c, s = cos[:, :, k], sin[:, :, k]
        y, z = c * y + s * z, c * z - s * y
        pos[:, :, k] = p
        rot[:, :, k, :, 0], rot[:, :, k, :, 1], rot[:, :, k, :, 2] = x, y, z
        p = p + z * SEGMENT_LENGTHS[None, :, k, None]
    pos[:, :, 3] = p
    rot[:, :, 3] = rot[:, :, 2]
    return pos, rot


def forward_kinematics(palm_pose: np.ndarray, joint_angles: np.ndarray, side: str,
                       geometry: HandGeometry = DEFAULT_GEOMETRY) -> tuple[np.ndarray, np.ndarray]:
    """Palm poses (n, 6) and joint angles (n, 15) -> joint poses (n, 90) and keypoints (n, 36).

    Joint poses: the 15 joint frames in :data:`JOINT_NAMES` order, each
    ``(x, y, z, roll, pitch, yaw)``; a joint's frame sits at the joint and carries the
    child segment's orientation. Keypoints: the 5 fingertips (thumb..little), then
    the wrist (oriented like the palm).
    """
    palm = np.atleast_2d(np.asarray(palm_pose, dtype=np.float64))
    pos, rot = chain_frames(palm, joint_angles, side, geometry)
    n = palm.shape[0]
    poses = np.concatenate([pos, matrix_to_euler(rot)], axis=-1)  # (n, 5, 4, 6)
    joint_poses = poses[:, :, :3].reshape(n, 90)
    r_palm = euler_to_matrix(palm[:, 3:])
    wrist = np.concatenate([palm[:, :3] + r_palm @ np.asarray(WRIST_OFFSET), palm[:, 3:]], axis=-1)
    keypoints = np.concatenate([poses[:, :, 3], wrist[:, None]], axis=1).reshape(n, 36)
    return joint_poses, keypoints


def fingertip_positions(palm_pose: np.ndarray, joint_angles: np.ndarray, side: str,
                        geometry: HandGeometry = DEFAULT_GEOMETRY) -> np.ndarray:
    """(n, 5, 3) fingertip positions (thumb..little)."""
    return chain_frames(palm_pose, joint_angles, side, geometry)[0][:, :, 3]


def within_limits(joint_angles: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """(n,) whether every joint lies inside its limits."""
    q = np.atleast_2d(joint_angles)
    return np.all((q >= JOINT_LOWER - tol) & (q <= JOINT_UPPER + tol), axis=-1)
