"""The ground-truth grasp configuration, sized to the object.

The hand hovers with its palm centre :data:`schemas.scene.PALM_HOVER` above the
object's top, right above its centre, palm down. Each finger then closes along a
fixed synergy (its three joints in a fixed ratio) until its capsule first touches the
object, or to the synergy's end if it never does. So larger objects get less flexion.
The object sits in a canonical placement: a lying cylinder's axis across the palm
(along world X, as when it rolls toward or away from the camera), an upright one's
vertical, a box aligned with the world axes.

A :class:`GraspDesign` names the hand geometry (:class:`generators.hand.HandGeometry`),
the hover height and the synergy; :data:`DEFAULT_DESIGN` is the dataset's. A design with
``as_placed`` sizes a lying cylinder's grasp for its axis as it lies (``yaw``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from generators.contact import signed_distance_local
from generators.hand import (
    DEFAULT_GEOMETRY,
    FINGER_RADII,
    JOINT_LOWER,
    JOINT_UPPER,
    OPPOSED_THUMB,
    REST_JOINTS,
    SIDES,
    SPLAYED_THUMB,
    HandGeometry,
    chain_frames,
)
from schemas.errors import SpecError
from schemas.names import shorten
from schemas.objects import object_category
from schemas.scene import PALM_HOVER
from schemas.versions import DATASET_VERSION

#: Joint angles at the end of each finger's synergy (thumb, index, middle, ring, little).
SYNERGY_END = np.array(
    [
        [1.00, 0.80, 1.00],
        [1.45, 1.60, 1.10],
        [1.45, 1.60, 1.10],
        [1.45, 1.60, 1.10],
        [1.45, 1.60, 1.10],
    ]
)
_GRID = 49
_SAMPLES_PER_SEGMENT = 4


@dataclass(frozen=True)
class GraspDesign:
    """How the ground truth grasps: the ``hand`` geometry; ``hover``, the palm centre's
    height over the object's top (units); ``synergy_end``, the 15 joint angles each
    finger's synergy ends at (:data:`JOINT_NAMES` order); ``as_placed``, whether a lying
    cylinder's grasp is sized for its axis as it lies (else along X);
    ``hover_by_object``: (category, hover) pairs overriding ``hover`` for those objects;
    ``low_objects``: categories the palm grasps as low as the closing fingers allow (the
    lowest hover from ``min_hover`` to ``max_hover``, in 0.01 steps, whose finger capsules
    stay ``table_clearance`` over the table); ``turn_to_axis``: whether the palm turns about
    the vertical so that the fingers close across a lying cylinder's axis (once, on the
    approach); ``wrist_reflex``: whether it turns by the hand's own rule instead, as the
    fingers close (:mod:`generators.wrist`)."""

    name: str
    hand: HandGeometry
    hover: float
    synergy_end: tuple[float, ...]
    as_placed: bool
    hover_by_object: tuple[tuple[str, float], ...] = ()
    low_objects: tuple[str, ...] = ()
    min_hover: float = 0.15
    max_hover: float = 0.6
    table_clearance: float = 0.0
    turn_to_axis: bool = False
    wrist_reflex: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.hand, HandGeometry):
            raise SpecError(f"grasp design {self.name!r}: hand must be a HandGeometry, got {shorten(repr(self.hand))}")
        for hover in (self.hover, self.min_hover, self.max_hover, *(h for _, h in self.hover_by_object)):
            if isinstance(hover, bool) or not isinstance(hover, numbers.Real) or not 0.0 < hover < 2.0:
                raise SpecError(f"grasp design {self.name!r}: a hover must be a number in (0, 2), got {shorten(repr(hover))}")
        for category in (*(c for c, _ in self.hover_by_object), *self.low_objects):
            object_category(category)
        if not isinstance(self.table_clearance, numbers.Real) or not -0.05 <= self.table_clearance <= 0.5:
            raise SpecError(f"grasp design {self.name!r}: table_clearance must be in [-0.05, 0.5], "
                            f"got {shorten(repr(self.table_clearance))}")
        if self.turn_to_axis and self.wrist_reflex:
            raise SpecError(f"grasp design {self.name!r}: the palm turns on the approach or by the wrist reflex, not both")
        end = np.asarray(self.synergy_end, dtype=np.float64)
        if end.shape != (15,) or np.any(end < JOINT_LOWER) or np.any(end > JOINT_UPPER):
            raise SpecError(f"grasp design {self.name!r}: synergy_end must be 15 angles within the joint limits, "
                            f"got {shorten(repr(self.synergy_end))}")

    def hover_for(self, category: str) -> float:
        """The palm centre's fixed height over ``category``'s top (units), unless it is one
        of ``low_objects``."""
        return dict(self.hover_by_object).get(category, self.hover)


#: The dataset's grasp up to 4.x: the splayed thumb, hovering PALM_HOVER over the top.
SPLAYED = GraspDesign("splayed", SPLAYED_THUMB, PALM_HOVER, tuple(float(a) for a in SYNERGY_END.reshape(15)), False)
_LYING = ("soda_can", "water_bottle", "paper_roll")
#: The opposable thumb's grasp (docs/concepts/grasp-hold.md, benchmarks/hold_grasp_design.py):
#: the fingers' synergy leads with the proximal joint (they reach down past the object
#: before curling under it); boxes from 0.1-0.15 higher (at PALM_HOVER the curled fingers
#: reach under the table beside a low box); lying cylinders with the palm turned across
#: their axis and as low as the closing fingers allow (at least 1 mm over the top, finger
#: capsules at most 0.04 into the table: the hand body allows 0.05), so that the fingers
#: and the thumb close under the cylinder's equator.
OPPOSED = GraspDesign(
    "opposed", OPPOSED_THUMB, PALM_HOVER, (1.2, 0.8, 1.0) + (1.6, 1.0, 0.5) * 4, True,
    hover_by_object=(("cracker_box", 0.45), ("sugar_box", 0.5), ("toy_cube", 0.45)),
    low_objects=_LYING, min_hover=0.13, max_hover=0.6, table_clearance=-0.04, turn_to_axis=True,
)
#: :data:`OPPOSED` with the palm kept in the rest orientation (the action steers no turn):
#: lying cylinders are sized as they lie, and the fingers close along the axis where it
#: runs along Z.
OPPOSED_FIXED = dataclasses.replace(OPPOSED, name="opposed-fixed", turn_to_axis=False)
#: :data:`OPPOSED` with the palm turned by the wrist reflex (:mod:`generators.wrist`), part
#: of the hand, not of the 18-number action: as the fingers start closing over a lying
#: cylinder, the palm turns toward its axis at most 10 rad/s.
OPPOSED_WRIST = dataclasses.replace(OPPOSED, name="opposed-wrist", turn_to_axis=False, wrist_reflex=True)
#: Every grasp design by name.
DESIGNS = MappingProxyType({d.name: d for d in (SPLAYED, OPPOSED, OPPOSED_FIXED, OPPOSED_WRIST)})
#: The dataset's grasp: the design of the dataset's hand, :data:`generators.hand.DEFAULT_GEOMETRY`
#: (switching that one name switches the hand and its grasp together): the opposed thumb
#: with the wrist reflex (5.x), the splayed thumb up to 4.x (:data:`VERSION_DESIGNS`).
DEFAULT_DESIGN = {SPLAYED_THUMB.name: SPLAYED, OPPOSED_THUMB.name: OPPOSED_WRIST}[DEFAULT_GEOMETRY.name]


def _finger_clearance(palm_pose: np.ndarray, closure: np.ndarray, category: str, size: float, side: str,
                      design: GraspDesign = DEFAULT_DESIGN, yaw: float = 0.0) -> np.ndarray:
    """(len(closure), 5) clearance of each finger's capsules at each closure fraction."""
    cat = object_category(category)
    end = np.asarray(design.synergy_end)
    q = REST_JOINTS + closure[:, None] * (end - REST_JOINTS)
    pos, _ = chain_frames(np.repeat(palm_pose[None], len(closure), axis=0), q, side, design.hand)
    w = np.linspace(0.0, 1.0, _SAMPLES_PER_SEGMENT, endpoint=False)
    starts, ends = pos[:, :, :3], pos[:, :, 1:]
    points = starts[:, :, :, None] + w[:, None] * (ends - starts)[:, :, :, None]
    points = np.concatenate([points.reshape(len(closure), 5, -1, 3), pos[:, :, 3:]], axis=2)
    local = points - np.array([0.0, cat.half_height(size), 0.0])
    if yaw:  # into the frame of a cylinder whose axis is turned by yaw about +Y from +X
        c, s = math.cos(yaw), math.sin(yaw)
        local = np.stack([c * local[..., 0] - s * local[..., 2], local[..., 1],
                          s * local[..., 0] + c * local[..., 2]], axis=-1)
    axis = cat.geometry.axis(cat.lying)  # world axis of a cylinder in the canonical placement
    dist = signed_distance_local(local, cat.shape, cat.scaled_dims(size), axis)
    return dist.min(axis=-1) - FINGER_RADII


@functools.lru_cache(maxsize=4096)
def _grasp_angles(category: str, size: float, side: str, design: GraspDesign, yaw: float,
                  hover: float) -> tuple[float, ...]:
    cat = object_category(category)
    top = 2.0 * cat.half_height(size)
    palm = np.array([0.0, top + hover, 0.0, 0.0, 0.0, 0.0])
    grid = np.linspace(0.0, 1.0, _GRID)
    clearance = _finger_clearance(palm, grid, category, size, side, design, yaw)
    closure = np.ones(5)
    for f in range(5):
        hit = np.flatnonzero(clearance[:, f] <= 0.0)
        if len(hit) == 0:
            continue
        k = hit[0]
        if k == 0:
            closure[f] = 0.0
            continue
        c0, c1 = clearance[k - 1, f], clearance[k, f]
        closure[f] = grid[k - 1] + (grid[k] - grid[k - 1]) * c0 / (c0 - c1)
    end = np.asarray(design.synergy_end).reshape(5, 3)
    angles = REST_JOINTS + (closure[:, None] * (end - REST_JOINTS.reshape(5, 3))).reshape(15)
    return tuple(float(a) for a in np.clip(angles, JOINT_LOWER, JOINT_UPPER))


@functools.lru_cache(maxsize=4096)
def _lowest(category: str, size: float, side: str, design: GraspDesign, yaw: float, hover: float) -> tuple[float, float]:
    """The lowest fingertip and the lowest capsule surface, relative to the palm centre,
    while the fingers close from rest to the grasp (21 fractions of it)."""
    grasp = np.array(_grasp_angles(category, size, side, design, yaw, hover))
    closure = np.linspace(0.0, 1.0, 21)[:, None]
    joints = REST_JOINTS + closure * (grasp - REST_JOINTS)
    pos = chain_frames(np.zeros((len(closure), 6)), joints, side, design.hand)[0]
    # a capsule's lowest point is under one of its two end points
    return float(pos[:, :, 3, 1].min()), float((pos[..., 1] - FINGER_RADII[None, :, None]).min())


@functools.lru_cache(maxsize=4096)
def _hover(category: str, size: float, side: str, design: GraspDesign, yaw: float) -> float:
    if category not in design.low_objects:
        return design.hover_for(category)
    top = 2.0 * object_category(category).half_height(size)
    hover = design.min_hover
    for step in range(int(round((design.max_hover - design.min_hover) / 0.01)) + 1):
        hover = round(design.min_hover + 0.01 * step, 6)
        if top + hover + _lowest(category, size, side, design, yaw, hover)[1] >= design.table_clearance:
            break
    return hover


def _yaw(category: str, design: GraspDesign, yaw: float) -> float:
    """The yaw the grasp is sized for: 0 unless the design sizes a lying cylinder as placed
    (then ``yaw`` folded into [0, pi), the axis' symmetry, and rounded for the caches)."""
    if not (design.as_placed and object_category(category).lying):
        return 0.0
    if isinstance(yaw, bool) or not isinstance(yaw, numbers.Real) or not math.isfinite(yaw):
        raise SpecError(f"grasp yaw must be a finite number (radians), got {shorten(repr(yaw))}")
    return round(float(yaw) % math.pi, 9) % math.pi


def _checked(category: str, size: float, side: str, design: GraspDesign, yaw: float) -> tuple:
    _check(category, size, side)
    if not isinstance(design, GraspDesign):
        raise SpecError(f"grasp design must be a GraspDesign, got {shorten(repr(design))}")
    return category, float(size), side, design, _yaw(category, design, yaw)


def grasp_hover(category: str, size: float, side: str, design: GraspDesign = DEFAULT_DESIGN, yaw: float = 0.0) -> float:
    """The palm centre's height over the object's top (units) the ground truth grasps from."""
    return _hover(*_checked(category, size, side, design, yaw))


def lowest_fingertip_offset(category: str, size: float, side: str, design: GraspDesign = DEFAULT_DESIGN,
                            yaw: float = 0.0) -> float:
    """Lowest fingertip height relative to the palm centre (palm down) while the fingers
    close from rest to :func:`grasp_angles` (the synergy sampled at 21 fractions)."""
    args = _checked(category, size, side, design, yaw)
    return _lowest(*args, _hover(*args))[0]


def cylinder_yaw(quaternion: np.ndarray) -> float:
    """The yaw (radians, about +Y from +X) of a lying cylinder's axis (body +X) at the
    orientation ``quaternion`` (qx, qy, qz, qw)."""
    x, y, z, w = (float(v) for v in quaternion)
    axis_x, axis_z = 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * z - w * y)
    return math.atan2(-axis_z, axis_x)


def _check(category: str, size: float, side: str) -> None:
    """Validate before the caches, which would raise TypeError on unhashable arguments."""
    if not isinstance(category, str):
        raise SpecError(f"object must be a category name, got {shorten(repr(category))}")
    object_category(category)
    if not isinstance(side, str) or side not in SIDES:
        raise SpecError(f"hand side must be one of {list(SIDES)}, got {shorten(repr(side))}")
    if isinstance(size, bool) or not isinstance(size, numbers.Real) or not math.isfinite(size) or size <= 0:
        raise SpecError(f"object size must be a finite number > 0, got {shorten(repr(size))}")


def grasp_angles(category: str, size: float, side: str, design: GraspDesign = DEFAULT_DESIGN, yaw: float = 0.0) -> np.ndarray:
    """(15,) ground-truth joint angles (radians) grasping ``category`` of ``size`` with the
    ``side`` hand of ``design``; ``yaw``: a lying cylinder's axis relative to the palm
    (:func:`cylinder_yaw`), used when the design sizes it as placed."""
    args = _checked(category, size, side, design, yaw)
    return np.array(_grasp_angles(*args, _hover(*args)))


#: The ground truth's grasp of each readable dataset version (what its folders' grasp
#: angles and hands are): the splayed thumb up to 4.x.
VERSION_DESIGNS = MappingProxyType({"2.0.0": SPLAYED, "3.0.0": SPLAYED, "4.0.0": SPLAYED})


def design_of(dataset_version: object) -> GraspDesign:
    """The grasp design of folders of ``dataset_version`` (:data:`VERSION_DESIGNS`); the
    dataset's (:data:`DEFAULT_DESIGN`) for the current version or None (in-memory episodes)."""
    if dataset_version is None or dataset_version == DATASET_VERSION:
        return DEFAULT_DESIGN
    found = VERSION_DESIGNS.get(dataset_version) if isinstance(dataset_version, str) else None
    if found is None:
        raise SpecError(f"no grasp design known for dataset version {shorten(repr(dataset_version))} "
                        f"(known: {sorted(VERSION_DESIGNS)})")
    return found
