"""The hand of :mod:`generators.hand` as a URDF for pybullet, and helpers to pose it.

The base link is the palm (link frame = palm frame, inertial origin at the same
place, so pybullet's base position IS the palm centre). Each finger is a chain of
three revolute joints named as :data:`generators.hand.JOINT_NAMES`; fixed joints add
the links ``<finger>_tip`` (fingertip frames) and ``wrist``, so that pybullet link
states give the keypoints.

Posing it (what the renderer does), with ``body = p.loadURDF(write_hand_urdf(side, d),
useFixedBase=True)``::

    p.resetBasePositionAndOrientation(body, palm_pose[:3], p.getQuaternionFromEuler(palm_pose[3:]))
    for name, index in zip(JOINT_NAMES, joint_indices(body)):
        p.resetJointState(body, index, joint_angles[JOINT_NAMES.index(name)])

:func:`set_hand_state` does exactly that. Link frames are ``getLinkState(...)[4:6]``
(``worldLinkFramePosition/Orientation``).
"""

from __future__ import annotations

import os
import tempfile

import numpy as np

from generators.hand import (
    DEFAULT_GEOMETRY,
    FINGER_RADII,
    FINGERS,
    JOINT_LOWER,
    JOINT_NAMES,
    JOINT_UPPER,
    KEYPOINT_NAMES,
    PALM_HALF_EXTENTS,
    SEGMENT_LENGTHS,
    WRIST_OFFSET,
    HandGeometry,
    check_side,
    matrix_to_euler,
    root_positions,
    root_rotations,
)

SKIN = (0.93, 0.76, 0.64, 1.0)
PALM_SKIN = (0.88, 0.68, 0.56, 1.0)
NAIL = (0.98, 0.88, 0.84, 1.0)


def _f(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def _inertial(mass: float, z: float = 0.0) -> str:
    i = mass * 1e-3
    return (
        f'<inertial><origin xyz="0 0 {z:.9g}"/><mass value="{mass:.9g}"/>'
        f'<inertia ixx="{i}" ixy="0" ixz="0" iyy="{i}" iyz="0" izz="{i}"/></inertial>'
    )


def _segment_link(name: str, length: float, radius: float, material: str) -> str:
    """A finger segment along local +Z: a cylinder with a sphere at the joint."""
    shape = f'<cylinder radius="{radius:.9g}" length="{length:.9g}"/>'
    return (
        f'<link name="{name}">{_inertial(0.02)}'
        f'<visual><origin xyz="0 0 {length / 2:.9g}"/><geometry>{shape}</geometry>'
        f'<material name="{material}"/></visual>'
        f'<visual><geometry><sphere radius="{radius:.9g}"/></geometry><material name="{material}"/></visual>'
        f'<collision><origin xyz="0 0 {length / 2:.9g}"/><geometry>{shape}</geometry></collision>'
        "</link>"
    )


def hand_urdf(side: str, geometry: HandGeometry = DEFAULT_GEOMETRY) -> str:
    """URDF text of the ``side`` hand ("right" or "left") of ``geometry``; deterministic."""
    side = check_side(side)
    hx, hy, hz = PALM_HALF_EXTENTS
    roots, rots = root_positions(side, geometry), root_rotations(side, geometry)
    parts = [
        '<?xml version="1.0"?>',
        f'<robot name="dyana_hand_{side}">',
        f'<material name="skin"><color rgba="{_f(SKIN)}"/></material>',
        f'<material name="palm"><color rgba="{_f(PALM_SKIN)}"/></material>',
        f'<material name="nail"><color rgba="{_f(NAIL)}"/></material>',
        f'<link name="palm">{_inertial(0.4)}'
        f'<visual><geometry><box size="{_f((2 * hx, 2 * hy, 2 * hz))}"/></geometry><material name="palm"/></visual>'
        f'<collision><geometry><box size="{_f((2 * hx, 2 * hy, 2 * hz))}"/></geometry></collision></link>',
        f'<link name="wrist">{_inertial(0.01)}'
        f'<visual><origin xyz="0 0 -0.25"/><geometry><cylinder radius="{0.7 * hx:.9g}" length="0.5"/></geometry>'
        '<material name="palm"/></visual></link>',
        f'<joint name="wrist_fixed" type="fixed"><parent link="palm"/><child link="wrist"/>'
        f'<origin xyz="{_f(WRIST_OFFSET)}"/></joint>',
    ]
    for f, finger in enumerate(FINGERS):
        parent = "palm"
        for k in range(3):
            joint = JOINT_NAMES[3 * f + k]
            child = f"{finger}_{k + 1}"
            if k == 0:
                origin = f'<origin xyz="{_f(roots[f])}" rpy="{_f(matrix_to_euler(rots[f]))}"/>'
            else:
                origin = f'<origin xyz="0 0 {SEGMENT_LENGTHS[f, k - 1]:.9g}"/>'
            parts.append(_segment_link(child, SEGMENT_LENGTHS[f, k], FINGER_RADII[f], "skin"))
            parts.append(
                f'<joint name="{joint}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
                f'{origin}<axis xyz="1 0 0"/>'
                f'<limit lower="{JOINT_LOWER[3 * f + k]:.9g}" upper="{JOINT_UPPER[3 * f + k]:.9g}" '
                'effort="10" velocity="20"/></joint>'
            )
            parent = child
        parts.append(
            f'<link name="{finger}_tip">{_inertial(0.005)}'
            f'<visual><geometry><sphere radius="{FINGER_RADII[f] * 0.999:.9g}"/></geometry>'
            '<material name="nail"/></visual></link>'
        )
        parts.append(
            f'<joint name="{finger}_tip_fixed" type="fixed"><parent link="{parent}"/>'
            f'<child link="{finger}_tip"/><origin xyz="0 0 {SEGMENT_LENGTHS[f, 2]:.9g}"/></joint>'
        )
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def write_hand_urdf(side: str, directory: str, geometry: HandGeometry = DEFAULT_GEOMETRY) -> str:
    """Write ``dyana_hand_<side>.urdf`` (``dyana_hand_<side>_<geometry>.urdf`` for another
    geometry than the dataset's) into ``directory`` (atomically) and return its path."""
    text = hand_urdf(side, geometry)
    name = side if geometry == DEFAULT_GEOMETRY else f"{side}_{geometry.name}"
    path = os.path.join(directory, f"dyana_hand_{name}.urdf")
    fd, tmp = tempfile.mkstemp(prefix=f".dyana_hand_{side}.", suffix=".urdf", dir=directory)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def pybullet_joint_order() -> tuple[str, ...]:
    """URDF names of the 15 revolute joints, in ``joint_angles`` order."""
    return JOINT_NAMES


def link_indices(body: int, client: int = 0) -> dict[str, int]:
    """pybullet index of every named joint/link of a loaded hand (joint index == child link index)."""
    from generators.bullet import p

    out: dict[str, int] = {}
    for i in range(p.getNumJoints(body, physicsClientId=client)):
        info = p.getJointInfo(body, i, physicsClientId=client)
        out[info[1].decode()] = i
        out[info[12].decode()] = i
    return out


def joint_indices(body: int, client: int = 0) -> np.ndarray:
    """(15,) pybullet joint indices in ``joint_angles`` order."""
    names = link_indices(body, client)
    return np.array([names[n] for n in JOINT_NAMES], dtype=np.int64)


def keypoint_link_indices(body: int, client: int = 0) -> np.ndarray:
    """(6,) pybullet link indices of the keypoints (5 fingertips, wrist)."""
    names = link_indices(body, client)
    return np.array([names[n] for n in KEYPOINT_NAMES], dtype=np.int64)


def set_hand_state(body: int, palm_pose, joint_angles, client: int = 0, indices: np.ndarray | None = None) -> None:
    """Pose a loaded hand: palm pose (6,) and joint angles (15,), velocities zero. Two
    pybullet calls (the joints in one ``resetJointStatesMultiDof``, so the link transforms
    are computed once), the state of one ``resetJointState`` per joint."""
    from generators.bullet import p

    palm = [float(v) for v in palm_pose]
    p.resetBasePositionAndOrientation(
        body, palm[:3], p.getQuaternionFromEuler(palm[3:]), physicsClientId=client
    )
    idx = joint_indices(body, client) if indices is None else indices
    p.resetJointStatesMultiDof(
        body,
        [int(i) for i in idx],
        [[float(a)] for a in joint_angles],
        targetVelocities=[[0.0]] * len(idx),
        physicsClientId=client,
    )
