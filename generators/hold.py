"""The hold test: does a closed hand hold the object when it lifts? (issue 38, S_hold).

From the first frame the grasp closes (:func:`schemas.events.grasp_closed`), the object
leaves its scripted motion for rigid-body dynamics: a reset pybullet DIRECT client (one
per thread) builds the table (the plane Y = 0), the object as a dynamic body released with its
velocity and angular velocity at that frame, and the hand of :mod:`generators.hand` as
a multibody of collision shapes (palm box, one capsule per finger segment) at that
frame's state. The fingers keep squeezing: each joint is position-controlled to its
angle plus :data:`GRIP_OVERSHOOT` with at most :data:`GRIP_TORQUE`, so a finger that
touches the object presses on it and one that does not closes a little further. The
palm is driven along a fixed path: it keeps its horizontal velocity, which decays to
zero, while it rises :data:`LIFT_HEIGHT` over :data:`LIFT_SECONDS` (both minimum
jerk), then stays still for :data:`HOLD_SECONDS`. The object is held when, at the end,
its centre is within :data:`SLIP_TOLERANCE` of where it started in the palm's frame,
and the hand did not start inside it (deeper than :data:`PENETRATION_TOLERANCE`).

Units are the scene's (1 unit = 10 cm, seconds, kilograms), so gravity is 98.1 units/s^2
and a torque of 1 N m is 100 kg unit^2/s^2. Fixed time step, a fixed solver iteration
count, deterministic pair ordering and one thread: the same inputs give the same bytes.
Every constant and why: ``docs/concepts/grasp-hold.md``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from generators.bullet import p, physics_client
from generators.hand import (
    DEFAULT_GEOMETRY,
    FINGER_RADII,
    JOINT_LOWER,
    JOINT_UPPER,
    PALM_HALF_EXTENTS,
    SEGMENT_LENGTHS,
    HandGeometry,
    check_side,
    root_positions,
    root_rotations,
)
from generators.hold_params import (
    GRAVITY,
    GRIP_OVERSHOOT,
    GRIP_TORQUE,
    HAND_FORCE,
    HAND_FRICTION,
    HOLD_SECONDS,
    LIFT_HEIGHT,
    LIFT_SECONDS,
    PALM_MASS,
    PENETRATION_TOLERANCE,
    SEGMENT_MASS,
    SLIP_TOLERANCE,
    SOLVER_ITERATIONS,
    STEPS_PER_SECOND,
    TABLE_FRICTION,
    object_friction,
    object_mass,
)
from schemas.errors import SpecError
from schemas.objects import object_category
from schemas.rotations import euler_to_quaternion, matrix_to_quaternion, quaternion_to_matrix


@dataclass(frozen=True)
class HoldResult:
    """What the hold test saw. ``held``: the hand did not start inside the object (by
    more than :data:`PENETRATION_TOLERANCE`) and the object's centre ended within
    :data:`SLIP_TOLERANCE` of its start in the palm's frame; ``slip``: that distance
    (units); ``rise``: how far the object's centre rose (units); ``contacts``: hand
    links (palm, segments) touching the object at the end; ``penetration``: how deep the
    hand was inside the object at the start (units, 0 when apart)."""

    held: bool
    slip: float
    rise: float
    contacts: int
    penetration: float

    def __post_init__(self) -> None:
        if not all(np.isfinite(v) for v in (self.slip, self.rise, self.penetration)):
            raise SpecError(f"hold result: slip, rise and penetration must be finite, got "
                            f"{self.slip!r}, {self.rise!r}, {self.penetration!r}")


def _vector(name: str, value, n: int) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise SpecError(f"hold test: {name} must be {n} finite numbers, got {np.asarray(value).shape} {value!r}"[:200])
    return arr


def minimum_jerk(s: np.ndarray) -> np.ndarray:
    """10 s^3 - 15 s^4 + 6 s^5 on [0, 1], clipped."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def palm_path(start: np.ndarray, velocity: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(n, 3) palm positions at times ``t`` (s) after the start: the horizontal velocity
    decays as 1 - minimum_jerk(t / LIFT_SECONDS) (travelling velocity * LIFT_SECONDS / 2
    in all), the height rises by LIFT_HEIGHT with a minimum-jerk profile, then still."""
    s = np.clip(np.asarray(t, dtype=np.float64) / LIFT_SECONDS, 0.0, 1.0)[:, None]
    glide = s - s**4 * (2.5 + s * (-3.0 + s))  # integral of 1 - minimum_jerk from 0 to s
    out = start + glide * LIFT_SECONDS * np.array([velocity[0], 0.0, velocity[2]])
    out[:, 1] += LIFT_HEIGHT * minimum_jerk(s[:, 0])
    return out


def _hand_body(client: int, side: str, palm_pose: np.ndarray, joint_angles: np.ndarray, geometry: HandGeometry) -> int:
    """The hand as one multibody: the palm box as base, 15 capsule links (3 per finger)."""
    kw = {"physicsClientId": client}
    palm_shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(PALM_HALF_EXTENTS), **kw)
    roots, rots = root_positions(side, geometry), root_rotations(side, geometry)
    shapes, parents, positions, orientations = [], [], [], []
    for f in range(5):
        for k in range(3):
            length = float(SEGMENT_LENGTHS[f, k])
            shapes.append(p.createCollisionShape(p.GEOM_CAPSULE, radius=float(FINGER_RADII[f]), height=length,
                                                 collisionFramePosition=[0.0, 0.0, length / 2.0], **kw))
            parents.append(0 if k == 0 else len(shapes) - 1)  # 0 is the base; link i is i + 1
            positions.append(roots[f].tolist() if k == 0 else [0.0, 0.0, float(SEGMENT_LENGTHS[f, k - 1])])
            orientations.append(matrix_to_quaternion(rots[f]).tolist() if k == 0 else [0.0, 0.0, 0.0, 1.0])
    n = len(shapes)
    body = p.createMultiBody(
        baseMass=PALM_MASS, baseCollisionShapeIndex=palm_shape, baseVisualShapeIndex=-1,
        basePosition=palm_pose[:3].tolist(), baseOrientation=euler_to_quaternion(palm_pose[3:]).tolist(),
        linkMasses=[SEGMENT_MASS] * n, linkCollisionShapeIndices=shapes, linkVisualShapeIndices=[-1] * n,
        linkPositions=positions, linkOrientations=orientations,
        linkInertialFramePositions=[[0.0, 0.0, 0.0]] * n, linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * n,
        linkParentIndices=parents, linkJointTypes=[p.JOINT_REVOLUTE] * n, linkJointAxis=[[1.0, 0.0, 0.0]] * n,
        **kw,
    )
    for j in range(n):
        p.resetJointState(body, j, float(joint_angles[j]), **kw)
    for link in range(-1, n):
        p.changeDynamics(body, link, lateralFriction=HAND_FRICTION, **kw)
    target = np.clip(joint_angles + GRIP_OVERSHOOT, JOINT_LOWER, JOINT_UPPER)
    p.setJointMotorControlArray(body, list(range(n)), p.POSITION_CONTROL, targetPositions=target.tolist(),
                                forces=[GRIP_TORQUE] * n, **kw)
    return body


def _object_body(client: int, name: str, size: float, pose: np.ndarray) -> int:
    """The object as one dynamic rigid body made of its shape's convex solid."""
    kw = {"physicsClientId": client}
    cat = object_category(name)
    solid = cat.geometry.solid(cat.scaled_dims(size), cat.lying)
    frame = matrix_to_quaternion(np.eye(3)[:, list(solid.axes)]).tolist()
    if solid.kind == "sphere":
        shape = p.createCollisionShape(p.GEOM_SPHERE, radius=solid.dims[0], **kw)
    elif solid.kind == "cylinder":
        shape = p.createCollisionShape(p.GEOM_CYLINDER, radius=solid.dims[0], height=2.0 * solid.dims[1],
                                       collisionFrameOrientation=frame, **kw)
    else:
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(solid.dims), collisionFrameOrientation=frame, **kw)
    body = p.createMultiBody(baseMass=object_mass(name, size), baseCollisionShapeIndex=shape,
                             basePosition=pose[:3].tolist(), baseOrientation=pose[3:].tolist(), **kw)
    p.changeDynamics(body, -1, lateralFriction=object_friction(name), **kw)
    return body


_LOCAL = threading.local()
#: Results of this process's hold tests by their exact inputs (the test is a pure function of
#: them): a run scored again (another reading, a chance row, a second table) costs nothing.
MEMO: dict[tuple, HoldResult] = {}
MEMO_SIZE = 8192


def _client() -> int:
    """This thread's physics-only client (:func:`generators.bullet.physics_client`), made once
    (connecting costs more than a test's set-up); every test starts with ``resetSimulation``,
    so no state carries over (tested)."""
    client = getattr(_LOCAL, "client", None)
    if client is None or not p.isConnected(client):
        client = _LOCAL.client = physics_client()
    return client


def _relative(palm_pos, palm_quat, obj_pos) -> np.ndarray:
    """The object's centre in the palm's frame."""
    rot = quaternion_to_matrix(np.asarray(palm_quat, dtype=np.float64))
    return rot.T @ (np.asarray(obj_pos, dtype=np.float64) - np.asarray(palm_pos, dtype=np.float64))


def hold_test(object_name: str, object_size: float, side: str, palm_pose, palm_velocity, joint_angles,
              object_pose, object_velocity, object_angular_velocity,
              geometry: HandGeometry = DEFAULT_GEOMETRY) -> HoldResult:
    """Run the hold test from one closing frame's state.

    ``palm_pose`` (6,) as :mod:`generators.hand`; ``palm_velocity`` (3,) units/s;
    ``joint_angles`` (15,) radians; ``object_pose`` (7,) x, y, z, qx, qy, qz, qw;
    ``object_velocity`` and ``object_angular_velocity`` (3,) world frame, units/s and
    rad/s; ``geometry`` the hand's (:class:`generators.hand.HandGeometry`). Pure: the physics
    starts from nothing in every call; same inputs, same result."""
    side = check_side(side)
    cat = object_category(object_name)
    lo, hi = cat.size_range
    if isinstance(object_size, bool) or not isinstance(object_size, (int, float, np.floating)) or not lo <= object_size <= hi:
        raise SpecError(f"hold test: object size must be a number in [{lo:.3g}, {hi:.3g}], got {object_size!r}"[:200])
    palm = _vector("palm_pose", palm_pose, 6)
    palm_v = _vector("palm_velocity", palm_velocity, 3)
    joints = _vector("joint_angles", joint_angles, 15)
    pose = _vector("object_pose", object_pose, 7)
    pose[3:] /= np.linalg.norm(pose[3:]) or 1.0
    obj_v = _vector("object_velocity", object_velocity, 3)
    obj_w = _vector("object_angular_velocity", object_angular_velocity, 3)
    key = (object_name, float(object_size), side, geometry,
           *(v.tobytes() for v in (palm, palm_v, joints, pose, obj_v, obj_w)))
    known = MEMO.get(key)
    if known is not None:
        return known
    result = _simulate(object_name, float(object_size), side, palm, palm_v, joints, pose, obj_v, obj_w, geometry)
    if len(MEMO) >= MEMO_SIZE:
        MEMO.pop(next(iter(MEMO)))
    MEMO[key] = result
    return result


def _simulate(object_name: str, object_size: float, side: str, palm: np.ndarray, palm_v: np.ndarray, joints: np.ndarray,
              pose: np.ndarray, obj_v: np.ndarray, obj_w: np.ndarray, geometry: HandGeometry) -> HoldResult:
    """The hold test's physics on checked inputs (:func:`hold_test`)."""
    client = _client()
    kw = {"physicsClientId": client}
    p.resetSimulation(**kw)  # the previous test's bodies stay until here: freeing them is the same cost
    p.setPhysicsEngineParameter(fixedTimeStep=1.0 / STEPS_PER_SECOND, numSubSteps=0,
                                numSolverIterations=SOLVER_ITERATIONS, deterministicOverlappingPairs=1, **kw)
    p.setGravity(0.0, -GRAVITY, 0.0, **kw)
    table = p.createMultiBody(0.0, p.createCollisionShape(p.GEOM_PLANE, planeNormal=[0.0, 1.0, 0.0], **kw), **kw)
    p.changeDynamics(table, -1, lateralFriction=TABLE_FRICTION, **kw)
    hand = _hand_body(client, side, palm, joints, geometry)
    obj = _object_body(client, object_name, object_size, pose)
    for link in range(-1, 15):  # the table carries the object only
        p.setCollisionFilterPair(hand, table, link, -1, 0, **kw)
    p.resetBaseVelocity(hand, palm_v.tolist(), [0.0, 0.0, 0.0], **kw)
    p.resetBaseVelocity(obj, obj_v.tolist(), obj_w.tolist(), **kw)
    quat = euler_to_quaternion(palm[3:]).tolist()
    drive = p.createConstraint(hand, -1, -1, -1, p.JOINT_FIXED, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                               palm[:3].tolist(), childFrameOrientation=quat, **kw)
    start = _relative(palm[:3], quat, pose[:3])
    p.performCollisionDetection(**kw)
    depth = max([0.0] + [-c[8] for c in p.getClosestPoints(hand, obj, 0.0, **kw)])
    steps = int(round((LIFT_SECONDS + HOLD_SECONDS) * STEPS_PER_SECOND))
    path = palm_path(palm[:3], palm_v, np.arange(1, steps + 1, dtype=np.float64) / STEPS_PER_SECOND)
    for target in path:
        p.changeConstraint(drive, target.tolist(), quat, maxForce=HAND_FORCE, **kw)
        p.stepSimulation(**kw)
    palm_pos, palm_quat = p.getBasePositionAndOrientation(hand, **kw)
    obj_pos, _ = p.getBasePositionAndOrientation(obj, **kw)
    contacts = len({c[3] for c in p.getContactPoints(hand, obj, **kw)})
    end = _relative(palm_pos, palm_quat, obj_pos)
    slip = float(np.linalg.norm(end - start))
    held = slip <= SLIP_TOLERANCE and depth <= PENETRATION_TOLERANCE
    return HoldResult(held=bool(held), slip=slip, rise=float(obj_pos[1] - pose[1]), contacts=contacts,
                      penetration=float(depth))
