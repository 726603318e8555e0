"""The hand as a pybullet body: an action is a target the hand follows within human-like
limits, and the hand does not enter the table, the obstacles or the object.

One :class:`HandBody` owns a pybullet DIRECT client with the hand's collision shapes
(the URDF of :mod:`generators.hand_urdf`: the palm box and one cylinder per finger
segment; and the wrist cylinder the URDF draws), the table top (the plane Y = 0 under
the whole palm box), the episode's obstacles and the object (its shape's main solid,
:mod:`schemas.shapes`; the mug's handle and the markings are left out). Bodies are
posed kinematically; the only physics asked of pybullet is its collision query
(``getClosestPoints``), single-threaded and without a time step, so a step's result is
a pure function of the state, the target and the object's pose. Each :meth:`HandBody.step`:

1. limits the target (:func:`limit_palm`, :func:`limit_joints`): the palm's velocity
   change per frame to :data:`PALM_MAX_ACCELERATION`, then its speed to
   :data:`PALM_MAX_SPEED` (both Euclidean, by scaling the vector); every joint's change
   to :data:`JOINT_MAX_SPEED`. A target within the limits is reached exactly.
2. checks the limited state: no part of the hand deeper than :data:`TOUCH` in the table
   or an obstacle, the palm centre inside the palm box if one is given, and the palm and
   wrist no deeper in the object (at its pose of the new frame) than they were before the
   move or :data:`TOUCH`, whichever is more: the object keeps its
   scripted motion and may run into the hand, the hand may not push further in. The
   fingers may close into the object's volume (the ground truth's grasps do, by up to
   0.39 units): they are stopped by the table and the obstacles only.
   If the state breaks a rule, the hand moves along the straight line from its
   previous state toward it, as far as :data:`BISECTIONS` halvings find allowed (no
   sliding along the surface it meets).

Constructed for a grasp design with the wrist reflex (by default the dataset's,
:data:`generators.grasp.DEFAULT_DESIGN` = ``OPPOSED_WRIST``), the palm's heading follows
:func:`generators.wrist.wrist_step` of the new state (as float32, as recorded): the turned
palm and wrist are checked as above, and a turn that breaks a rule stops where
:data:`BISECTIONS` halvings find allowed.

Docs: docs/concepts/hand-body.md (the limits, their sources and the ground truth's needs).
"""

from __future__ import annotations

import numpy as np

from generators.bullet import p, physics_client
from generators.clearance import WRIST_LENGTH, WRIST_RADIUS
from generators.grasp import DEFAULT_DESIGN, GraspDesign
from generators.hand import JOINT_LOWER, JOINT_UPPER, REST_JOINTS, REST_PALM, WRIST_OFFSET
from generators.scene import load_hand, set_hand_pose
from generators.wrist import wrist_step
from schemas.objects import object_category
from schemas.obstacles import Obstacle
from schemas.versions import FPS

#: Fastest palm speed (units/s; 35 = 3.5 m/s): the ground truth's planner refuses any
#: faster approach (:data:`generators.interception.MAX_PALM_SPEED`); it needs 22.1 at most.
PALM_MAX_SPEED = 35.0
#: Largest palm acceleration (units/s^2; 700 = 70 m/s^2): the ground truth needs 465 at
#: most; 700 = PALM_MAX_SPEED x FPS, so a stop at contact from full speed within one frame
#: is within the limit too, and every recorded palm obeys both limits.
PALM_MAX_ACCELERATION = PALM_MAX_SPEED * FPS
#: Fastest joint speed (rad/s, every joint): the ground truth's grasp closing needs 11.7.
JOINT_MAX_SPEED = 15.0
#: How deep a part of the hand may be in the table or an obstacle, or the palm in the
#: object (units; 0.05 = 5 mm, a finger pad pressed on a surface): contact, not entry.
#: The ground truth's finger segments reach 0.031 into the table.
TOUCH = 0.05
#: Halvings of a blocked move: the hand stops within 1/64 of the move short of contact
#: (0.027 units at full speed), and a blocked step costs about 1 ms more.
BISECTIONS = 6
#: The table's collision box: half extents and centre (its top the plane Y = 0).
TABLE_HALF = (50.0, 1.0, 50.0)
TABLE_CENTRE = (0.0, -1.0, 0.0)

_ORIENTATION = p.getQuaternionFromEuler([float(a) for a in REST_PALM[3:]])
#: The wrist cylinder's centre from the palm's (rest orientation: behind the wrist point along -Z).
_WRIST_CENTRE = np.asarray(WRIST_OFFSET) + np.array([0.0, 0.0, -WRIST_LENGTH / 2])


def limit_palm(palm: np.ndarray, velocity: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The palm position reached from ``palm`` moving at ``velocity`` (units per frame)
    toward ``target``: the velocity change clamped to the acceleration limit, then the
    speed to the speed limit; ``target`` itself when no clamp applies (float64)."""
    step = np.asarray(target, dtype=np.float64) - palm
    change = step - velocity
    a_max, v_max = PALM_MAX_ACCELERATION / FPS**2, PALM_MAX_SPEED / FPS
    norm = float(np.linalg.norm(change))
    if norm <= a_max and float(np.linalg.norm(step)) <= v_max:
        return np.asarray(target, dtype=np.float64).copy()
    if norm > a_max:
        change = change * (a_max / norm)
    new = velocity + change
    speed = float(np.linalg.norm(new))
    if speed > v_max:
        new = new * (v_max / speed)
    return palm + new


def limit_joints(joints: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``target`` with each joint's change from ``joints`` clamped to the speed limit (float64)."""
    w = JOINT_MAX_SPEED / FPS
    target = np.asarray(target, dtype=np.float64)
    return np.where(np.abs(target - joints) <= w, target, joints + np.clip(target - joints, -w, w))


def _collision_body(client: int, kind: int, position, orientation, **dims) -> int:
    shape = p.createCollisionShape(kind, physicsClientId=client, **dims)
    return p.createMultiBody(0.0, shape, -1, list(position), list(orientation), physicsClientId=client)


class HandBody:
    """The hand's collision body and state through one episode at a time (module docstring).

    :meth:`reset` starts an episode at the rest state; :meth:`step` moves toward a
    target; :meth:`close` frees the pybullet client."""

    def __init__(self, palm_box: tuple[np.ndarray, np.ndarray] | None = None,
                 design: GraspDesign = DEFAULT_DESIGN) -> None:
        """``palm_box``: (low, high) xyz the palm's centre must stay in (a wall like the others);
        ``design``: its hand and, if it has one, its wrist reflex (by default the dataset's)."""
        self._geometry = design.hand
        self._fist = np.asarray(design.synergy_end) if design.wrist_reflex else None
        self._box = None if palm_box is None else (np.asarray(palm_box[0], np.float64), np.asarray(palm_box[1], np.float64))
        self._client = physics_client()
        p.setPhysicsEngineParameter(fixedTimeStep=1.0 / FPS, deterministicOverlappingPairs=1, physicsClientId=self._client)
        self._table = _collision_body(self._client, p.GEOM_BOX, TABLE_CENTRE, (0, 0, 0, 1), halfExtents=TABLE_HALF)
        # the wrist (visual only in the URDF): its own body, posed with the palm (the palm
        # keeps the rest orientation, so the cylinder's axis stays along Z)
        self._wrist = _collision_body(self._client, p.GEOM_CYLINDER, (0.0, -50.0, 0.0), _ORIENTATION,
                                      radius=WRIST_RADIUS, height=WRIST_LENGTH)
        self._hands: dict[str, tuple[int, np.ndarray]] = {}
        self._scene: tuple[object, ...] | None = None
        self._static: tuple[int, ...] = ()
        self._object = -1
        self._category = ""
        self.palm = REST_PALM[:3].copy()
        self.joints = REST_JOINTS.astype(np.float64)
        self.velocity = np.zeros(3)
        self.heading = 0.0

    def reset(self, side: str, category: str, size: float, obstacles: tuple[Obstacle, ...]) -> None:
        """Start an episode: the hand at rest, not moving, in this scene."""
        client = self._client
        if side not in self._hands:
            self._hands[side] = load_hand(client, side, self._geometry)
        self._hand, self._indices = self._hands[side]
        scene = (category, size, obstacles)
        if scene != self._scene:
            for body in self._static[1:] + ((self._object,) if self._object >= 0 else ()):
                p.removeBody(body, physicsClientId=client)
            boxes = tuple(_collision_body(client, p.GEOM_BOX, o.position, o.quaternion, halfExtents=o.half_extents)
                          for o in obstacles)
            self._static = (self._table, *boxes)
            self._object = self._build_object(category, size)
            self._scene = scene
        self._category = category
        self.palm = REST_PALM[:3].copy()
        self.joints = REST_JOINTS.astype(np.float64)
        self.velocity = np.zeros(3)
        self.heading = 0.0

    def _build_object(self, category: str, size: float) -> int:
        cat = object_category(category)
        part = cat.geometry.visual_parts(cat.scaled_dims(size), cat.lying, cat.rgba, cat.rgba)[0]
        kind = {"sphere": p.GEOM_SPHERE, "cylinder": p.GEOM_CYLINDER, "box": p.GEOM_BOX}[part.kind]
        dims: dict[str, object] = (
            {"radius": part.dims[0]} if part.kind == "sphere"
            else {"radius": part.dims[0], "height": part.dims[1]} if part.kind == "cylinder"
            else {"halfExtents": part.dims}
        )
        shape = p.createCollisionShape(kind, collisionFramePosition=part.position,
                                       collisionFrameOrientation=part.orientation, physicsClientId=self._client, **dims)
        return p.createMultiBody(0.0, shape, -1, [0.0, -50.0, 0.0], [0, 0, 0, 1], physicsClientId=self._client)

    def depths(self, palm: np.ndarray, joints: np.ndarray, object_pose: np.ndarray,
               stop: float = np.inf, heading: float = 0.0) -> tuple[float, float]:
        """How deep the hand in this state (the palm turned ``heading`` about the vertical) is
        in the table or an obstacle, and how deep its palm or wrist is in the object at
        ``object_pose`` (x, y, z, qx, qy, qz, qw): 0 when clear. Once the first passes
        ``stop`` it is returned at once, the second as inf."""
        client = self._client
        turn = REST_PALM[3:] + np.array([0.0, heading, 0.0])
        set_hand_pose(client, self._hand, self._indices, np.concatenate([palm, turn]), joints)
        if heading:
            c, s = np.cos(heading), np.sin(heading)
            centre = np.array([c * _WRIST_CENTRE[0] + s * _WRIST_CENTRE[2], _WRIST_CENTRE[1],
                               -s * _WRIST_CENTRE[0] + c * _WRIST_CENTRE[2]])
            orientation = p.getQuaternionFromEuler([float(a) for a in turn])
        else:
            centre, orientation = _WRIST_CENTRE, _ORIENTATION
        wrist = [float(v) for v in palm + centre]
        p.resetBasePositionAndOrientation(self._wrist, wrist, orientation, physicsClientId=client)
        fixed = 0.0
        for body in self._static:
            for part in (self._hand, self._wrist):
                for point in p.getClosestPoints(part, body, 0.0, physicsClientId=client):
                    fixed = max(fixed, -point[8])
                if fixed > stop:
                    return fixed, np.inf
        pose = [float(v) for v in object_pose]
        p.resetBasePositionAndOrientation(self._object, pose[:3], pose[3:], physicsClientId=client)
        inside = 0.0
        for part in (self._hand, self._wrist):
            for point in p.getClosestPoints(part, self._object, 0.0, linkIndexA=-1, physicsClientId=client):
                inside = max(inside, -point[8])
        return fixed, inside

    def step(self, palm_target: np.ndarray, joint_target: np.ndarray, object_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Move one frame toward the targets (joints clipped to their limits), with the
        object at ``object_pose``; returns the new palm xyz and joints (float64 holding
        float32 values, the state as recorded)."""
        palm = limit_palm(self.palm, self.velocity, palm_target)
        joints = limit_joints(self.joints, np.clip(joint_target, JOINT_LOWER, JOINT_UPPER))
        before: list[float] = []  # the palm's depth in the object before the move, once needed

        def allowed(fraction: float) -> bool:
            at = self.palm + fraction * (palm - self.palm)
            if self._box is not None and (np.any(at < self._box[0]) or np.any(at > self._box[1])):
                return False
            fixed, inside = self.depths(at, self.joints + fraction * (joints - self.joints), object_pose, TOUCH, self.heading)
            if fixed > TOUCH:
                return False
            if inside <= TOUCH:
                return True
            if not before:
                before.append(self.depths(self.palm, self.joints, object_pose, heading=self.heading)[1])
            return inside <= before[0]

        # A hand that stays where it is moves into nothing: a refused move would keep the state
        # too (x + 0.0 is x bit for bit but for x = -0.0, so a state holding -0.0 is checked).
        still = (palm.tobytes() == self.palm.tobytes() and joints.tobytes() == self.joints.tobytes()
                 and not np.signbit(palm[palm == 0.0]).any() and not np.signbit(joints[joints == 0.0]).any())
        if not still and not allowed(1.0):
            low, high = 0.0, 1.0
            for _ in range(BISECTIONS):
                mid = 0.5 * (low + high)
                low, high = (mid, high) if allowed(mid) else (low, mid)
            palm, joints = self.palm + low * (palm - self.palm), self.joints + low * (joints - self.joints)
        # the state is kept as recorded (float32), so a replay of recorded actions meets the same state
        palm, joints = palm.astype(np.float32).astype(np.float64), joints.astype(np.float32).astype(np.float64)
        if self._fist is not None:
            self.heading = self._turn(palm, joints, object_pose)
        self.velocity = palm - self.palm
        self.palm, self.joints = palm, joints
        return palm, joints

    def _turn(self, palm: np.ndarray, joints: np.ndarray, object_pose: np.ndarray) -> float:
        """The wrist reflex's heading at the new state, as far toward it as the rules allow."""
        assert self._fist is not None
        heading = wrist_step(self.heading, palm, joints, object_pose, self._category, self._fist)
        if heading == self.heading:
            return heading
        before = self.depths(palm, joints, object_pose, heading=self.heading)[1]

        def allowed(fraction: float) -> bool:
            fixed, inside = self.depths(palm, joints, object_pose, TOUCH, self.heading + fraction * (heading - self.heading))
            return fixed <= TOUCH and inside <= max(TOUCH, before)

        if allowed(1.0):
            return heading
        low, high = 0.0, 1.0
        for _ in range(BISECTIONS):
            mid = 0.5 * (low + high)
            low, high = (mid, high) if allowed(mid) else (low, mid)
        return float(np.float32(self.heading + low * (heading - self.heading)))

    def close(self) -> None:
        """Disconnect the pybullet client (the body cannot step afterwards)."""
        if self._client >= 0:
            p.disconnect(physicsClientId=self._client)
            self._client = -1

