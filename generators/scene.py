"""The pybullet scene: floor, table, target objects and hands, built in a given client.

Coordinates are the world's (X right, Y up, Z forward, 1 unit = 10 cm); pybullet takes
them as they are (the renderer mirrors its image, see :mod:`generators.camera`).
Bodies are posed kinematically (``resetBasePositionAndOrientation``/``resetJointState``);
nothing here steps the simulation.

Object frames at identity orientation:

- sphere: centre at the origin;
- cylinder: axis along local +Y for upright categories, along local +X
  (:data:`LYING_AXIS`) for lying ones, so a lying cylinder at identity lies across
  the camera's view and rolls when it moves along Z;
- box: half extents ``(hx, hy, hz)`` along local X, Y, Z (``hy`` is the half height).

Obstacles (:class:`schemas.obstacles.Obstacle`) are plain boxes in their category's
colour, centred at ``(x, hy, z)`` and turned by ``yaw`` about +Y (the quaternion
``(0, sin(yaw/2), 0, cos(yaw/2))``, i.e. ``Ry(yaw)``, :mod:`generators.clearance`). They
are static within an episode: the renderer draws them into the episode's static plate.

Rolling objects carry markings (two crossing seams on spheres, two stripes along
lying cylinders) so that a viewer sees them turn. Markings stand out of the surface
by a few hundredths of the object's size; the resting geometry is unchanged.

The table top is drawn :data:`TABLE_TOP_GAP` below Y = 0 (0.001 unit, a tenth of a
millimetre, invisible at any resolution), so an object resting on the table never
ties in depth with it: the renderer's compositing would have to fall back to a full
render for such ties.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from dataclasses import dataclass

import numpy as np

from generators.bullet import p
from generators.hand import DEFAULT_GEOMETRY, HandGeometry
from generators.hand_urdf import joint_indices, set_hand_state, write_hand_urdf
from schemas.objects import object_category
from schemas.obstacles import Obstacle
from schemas.scene import TABLE_X, TABLE_Z
from schemas.shapes.base import IDENTITY

RGBA = tuple[float, float, float, float]

#: A lying cylinder's axis at identity orientation (object frame).
LYING_AXIS = (1.0, 0.0, 0.0)
#: An upright cylinder's axis at identity orientation (object frame).
UPRIGHT_AXIS = (0.0, 1.0, 0.0)

TABLE_TOP_GAP = 1e-3
TABLE_THICKNESS = 0.4
TABLE_BORDER = 0.4
FLOOR_Y = -6.0
TABLE_RGBA: RGBA = (0.32, 0.48, 0.46, 1.0)
TABLE_BORDER_RGBA: RGBA = (0.18, 0.28, 0.27, 1.0)
FLOOR_RGBA: RGBA = (0.55, 0.50, 0.45, 1.0)
# The floor is tiled around the table's footprint, in front of the camera: TinyRenderer
# tests every pixel of a triangle's bounding box and clips triangles that cross the
# camera plane at twice the cost, so one huge floor box nearly doubles a full render.
_FLOOR_HALF_X = 40.0
_FLOOR_NEAR_Z = (-2.0, 1.0)
_FLOOR_FAR_Z = (8.0, 45.0)
_FLOOR_SIDE_X = 7.0

#: Colour of each category's markings (seams, stripes, openings, labels).
MARKING_RGBA: dict[str, RGBA] = {
    "tennis_ball": (0.97, 0.97, 0.95, 1.0),
    "baseball": (0.80, 0.10, 0.10, 1.0),
    "orange": (0.35, 0.55, 0.10, 1.0),
    "soda_can": (0.85, 0.85, 0.88, 1.0),
    "water_bottle": (0.97, 0.97, 0.97, 1.0),
    "paper_roll": (0.45, 0.45, 0.50, 1.0),
    "mug": (0.08, 0.10, 0.18, 1.0),
    "cup": (0.05, 0.20, 0.10, 1.0),
    "cracker_box": (0.97, 0.90, 0.45, 1.0),
    "sugar_box": (0.20, 0.35, 0.75, 1.0),
    "toy_cube": (0.97, 0.97, 0.97, 1.0),
}

#: pybullet's geometry of each primitive solid a shape's visual parts are made of.
_SOLIDS = {"sphere": p.GEOM_SPHERE, "cylinder": p.GEOM_CYLINDER, "box": p.GEOM_BOX}


@dataclass(frozen=True)
class Part:
    """One visual primitive of a body, in the body's frame."""

    shape: int  # p.GEOM_SPHERE, p.GEOM_CYLINDER or p.GEOM_BOX
    dims: tuple[float, ...]  # (radius,), (radius, length) or half extents
    rgba: RGBA
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = IDENTITY


def _visual(client: int, part: Part) -> int:
    kwargs: dict[str, object] = {"rgbaColor": part.rgba, "visualFramePosition": part.position, "visualFrameOrientation": part.orientation}
    if part.shape == p.GEOM_SPHERE:
        kwargs["radius"] = part.dims[0]
    elif part.shape == p.GEOM_CYLINDER:
        kwargs["radius"], kwargs["length"] = part.dims
    else:
        kwargs["halfExtents"] = part.dims
    return p.createVisualShape(part.shape, physicsClientId=client, **kwargs)


def create_body(client: int, parts: list[Part], position=(0.0, 0.0, 0.0)) -> int:
    """A visual-only multibody: the first part on the base, each further part on a fixed link."""
    base, *links = [_visual(client, part) for part in parts]
    n = len(links)
    return p.createMultiBody(
        baseMass=0.0,
        baseCollisionShapeIndex=-1,
        baseVisualShapeIndex=base,
        basePosition=position,
        baseOrientation=IDENTITY,
        linkMasses=[0.0] * n,
        linkCollisionShapeIndices=[-1] * n,
        linkVisualShapeIndices=links,
        linkPositions=[(0.0, 0.0, 0.0)] * n,
        linkOrientations=[IDENTITY] * n,
        linkInertialFramePositions=[(0.0, 0.0, 0.0)] * n,
        linkInertialFrameOrientations=[IDENTITY] * n,
        linkParentIndices=[0] * n,
        linkJointTypes=[p.JOINT_FIXED] * n,
        linkJointAxis=[(0.0, 0.0, 1.0)] * n,
        physicsClientId=client,
    )


def static_parts() -> list[list[Part]]:
    """Floor and table as bodies of parts (world frame): floor tiles around the table's
    footprint (only where the camera can see the floor), then the table top and its
    darker border strips, tops at ``-TABLE_TOP_GAP``."""
    (x0, x1), (z0, z1) = TABLE_X, TABLE_Z
    b, t = TABLE_BORDER, TABLE_THICKNESS
    y = -TABLE_TOP_GAP - t / 2.0

    def box(cx, cz, hx, hz, rgba):
        return Part(p.GEOM_BOX, (hx, t / 2.0, hz), rgba, (cx, y, cz))

    def floor(xa, xb, za, zb):
        return Part(p.GEOM_BOX, ((xb - xa) / 2, 0.5, (zb - za) / 2), FLOOR_RGBA, ((xa + xb) / 2, FLOOR_Y - 0.5, (za + zb) / 2))

    zn, zf, xs = _FLOOR_NEAR_Z, _FLOOR_FAR_Z, _FLOOR_HALF_X
    tiles = [
        floor(-xs, xs, zf[0], zf[1]),
        floor(-xs, xs, zn[0], zn[1]),
        floor(-xs, -_FLOOR_SIDE_X, zn[1], zf[0]),
        floor(_FLOOR_SIDE_X, xs, zn[1], zf[0]),
    ]
    top = box((x0 + x1) / 2, (z0 + z1) / 2, (x1 - x0) / 2 - b, (z1 - z0) / 2 - b, TABLE_RGBA)
    near = box((x0 + x1) / 2, z0 + b / 2, (x1 - x0) / 2, b / 2, TABLE_BORDER_RGBA)
    far = box((x0 + x1) / 2, z1 - b / 2, (x1 - x0) / 2, b / 2, TABLE_BORDER_RGBA)
    left = box(x0 + b / 2, (z0 + z1) / 2, b / 2, (z1 - z0) / 2 - b, TABLE_BORDER_RGBA)
    right = box(x1 - b / 2, (z0 + z1) / 2, b / 2, (z1 - z0) / 2 - b, TABLE_BORDER_RGBA)
    return [[tile] for tile in tiles] + [[top], [near], [far], [left], [right]]


def build_static(client: int) -> tuple[int, ...]:
    """Create floor and table in ``client``; returns their body ids.

    Build them before any moving body: the renderer relies on static bodies being
    drawn first (see :mod:`generators.render`)."""
    return tuple(create_body(client, parts) for parts in static_parts())


def object_parts(name: str, size: float) -> list[Part]:
    """The visual parts of a category at ``size``, in the object's frame."""
    cat = object_category(name)
    dims = cat.scaled_dims(size)
    parts = [
        Part(_SOLIDS[v.kind], v.dims, v.rgba, v.position, v.orientation)
        for v in cat.geometry.visual_parts(dims, cat.lying, cat.rgba, MARKING_RGBA[name])
    ]
    if name == "mug":  # the handle: the category's, not its shape's
        r, length = dims
        parts.append(Part(p.GEOM_BOX, (0.18 * r, 0.28 * length, 0.08 * r), cat.rgba, (1.12 * r, 0.0, 0.0)))
    return parts


def build_object(client: int, name: str, size: float, position=(0.0, 0.0, 0.0)) -> int:
    """Create the object body of category ``name`` at ``size``; returns its body id."""
    return create_body(client, object_parts(name, size), position)


def obstacle_parts(obstacle: Obstacle) -> list[Part]:
    """The visual parts of an obstacle (one box), in a body frame at its centre."""
    return [Part(p.GEOM_BOX, obstacle.half_extents, obstacle.rgba, orientation=obstacle.quaternion)]


def build_obstacles(client: int, obstacles: tuple[Obstacle, ...]) -> tuple[int, ...]:
    """Create the obstacle bodies, in order; returns their body ids. Build them after the
    floor and table and before any moving body (see :mod:`generators.render`)."""
    return tuple(
        create_body(client, obstacle_parts(o), o.position) for o in obstacles
    )


_HAND_FILES: dict[tuple[int, str, str], str] = {}


def _remove_hand_files(pid: int, directory: str) -> None:
    if os.getpid() == pid:
        shutil.rmtree(directory, ignore_errors=True)


def hand_urdf_file(side: str, geometry: HandGeometry = DEFAULT_GEOMETRY) -> str:
    """This process's URDF file of the ``side`` hand of ``geometry``: written once into a temporary
    directory that is removed when the process exits (written again if it went missing).
    One path per side and geometry lets pybullet recognise a hand it loaded before."""
    key = (os.getpid(), side, geometry.name)
    path = _HAND_FILES.get(key)
    if path is None or not os.path.exists(path):
        directory = tempfile.mkdtemp(prefix="dyana_hand_")
        atexit.register(_remove_hand_files, key[0], directory)
        path = write_hand_urdf(side, directory, geometry)
        _HAND_FILES[key] = path
    return path


def load_hand(client: int, side: str, geometry: HandGeometry = DEFAULT_GEOMETRY) -> tuple[int, np.ndarray]:
    """Load the ``side`` hand (of ``geometry``) from its URDF with a fixed base; returns the body id and its
    (15,) joint indices in ``joint_angles`` order.

    With ``URDF_ENABLE_CACHED_GRAPHICS_SHAPES`` a client that loaded the same file before
    (and was not reset since) skips building the hand's convex hulls a second time for
    its GUI graphics (unused in DIRECT mode): 10.5 instead of 18 ms a hand. TinyRenderer's
    own shapes are built afresh on every load either way."""
    body = p.loadURDF(
        hand_urdf_file(side, geometry), useFixedBase=True, flags=p.URDF_ENABLE_CACHED_GRAPHICS_SHAPES, physicsClientId=client
    )
    return body, joint_indices(body, client)


def set_object_pose(client: int, body: int, object_pose) -> None:
    """Place an object body at ``object_pose`` (x, y, z, qx, qy, qz, qw)."""
    pose = [float(v) for v in object_pose]
    p.resetBasePositionAndOrientation(body, pose[:3], pose[3:], physicsClientId=client)


def set_hand_pose(client: int, body: int, indices: np.ndarray, palm_pose, joint_angles) -> None:
    """Pose a loaded hand: palm pose (6,), joint angles (15,)."""
    set_hand_state(body, palm_pose, joint_angles, client=client, indices=indices)
