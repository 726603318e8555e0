"""Where is the object? Localisation from one RGB frame, with public knowledge only.

A policy sees pixels, its own hand's state and the task text. What it may know
besides (the benchmark is public): the fixed camera (:mod:`generators.camera`), the
table's extent and its colour, the hand's geometry, and the object categories'
shapes (the text names the category). What it may not know: the object's size, hence
its height above the table, and where it is.

The recipe, per frame:

1. *Foreground*: pixels on the table top whose colour differs from the table's
   (measured once per episode as the median colour of the table region, robust to
   the few pixels that the object and hand cover).
2. *Hand*: the hand's own pixels are predicted from its proprioception (palm pose,
   joint and fingertip positions) by projecting its parts (palm box, wrist, finger
   capsules) with the camera model, and removed, with a margin of a few pixels for
   JPEG's ringing.
3. *Blob*: the largest connected foreground component, with the components close
   to it (a finger lying across the object splits it); its centroid is the object's
   image position.
4. *Back-projection*: the centroid's viewing ray meets the horizontal plane at the
   object's centre height, the category's resting half height at an estimated
   size. The size is estimated from the blob's area on frames where the hand does
   not touch the blob: the category's silhouette area at the nominal size is
   predicted by projecting the shape, and area scales with size squared. Until an
   estimate exists the nominal size is assumed; if the text names no known category,
   a fixed centre height :data:`DEFAULT_CENTRE_HEIGHT` is assumed.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import ndimage

from generators.camera import project, unproject_to_plane
from generators.hand import (
    FINGER_RADII,
    PALM_HALF_EXTENTS,
    WRIST_OFFSET,
    euler_to_matrix,
)
from generators.scene import TABLE_BORDER
from schemas.objects import OBJECTS, ObjectCategory
from schemas.scene import CAMERA_FOV_DEG, TABLE_X, TABLE_Z

#: A pixel is foreground when some channel differs from the table's colour by more.
COLOUR_THRESHOLD = 30
#: Extra pixels around the projected hand that count as hand (JPEG ringing, rounding).
HAND_MARGIN_PX = 2.0
#: Components smaller than this many pixels are noise.
MIN_BLOB_PX = 4
#: Assumed centre height (units) when the text names no known category.
DEFAULT_CENTRE_HEIGHT = 0.4
#: Estimated sizes are kept within this factor range of the category's nominal size.
SIZE_RANGE = (0.7, 1.3)
#: Wrist cylinder of the hand model: radius and its extent along the palm's local Z.
_WRIST_RADIUS = 0.7 * PALM_HALF_EXTENTS[0]
_WRIST_SPAN = (WRIST_OFFSET[2] - 0.5, WRIST_OFFSET[2])


def object_from_text(text: str) -> Optional[str]:
    """The object category the task text names (the longest matching name), or None."""
    lowered = " ".join(re.findall(r"[a-z]+", str(text).lower()))
    found = [name for name in OBJECTS if re.search(rf"\b{name.replace('_', ' ')}\b", lowered)]
    return max(found, key=len) if found else None


def focal_px(height: int) -> float:
    """The camera's focal length in pixels for images ``height`` pixels tall."""
    return (height / 2.0) / np.tan(np.radians(CAMERA_FOV_DEG) / 2.0)


@functools.lru_cache(maxsize=8)
def table_region(width: int, height: int) -> np.ndarray:
    """(H, W) bool: pixels whose ray meets the table top inside its border, less one pixel."""
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    world = unproject_to_plane(np.stack([cols, rows], axis=-1), width, height, 0.0)
    m = TABLE_BORDER + 0.05
    inside = (
        (world[..., 0] > TABLE_X[0] + m)
        & (world[..., 0] < TABLE_X[1] - m)
        & (world[..., 2] > TABLE_Z[0] + m)
        & (world[..., 2] < TABLE_Z[1] - m)
    )
    # the camera sees the whole table in front of it; rays pointing up never meet it
    inside &= np.isfinite(world).all(axis=-1)
    return ndimage.binary_erosion(inside, iterations=1)


def table_colour(image: np.ndarray) -> np.ndarray:
    """(3,) median RGB of the table region of ``image``: the table's rendered colour."""
    h, w = image.shape[:2]
    return np.median(image[table_region(w, h)], axis=0)


def _convex_hull(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (Andrew's monotone chain) of 2D points (m, 2)."""
    pts = sorted(map(tuple, np.round(points, 9)))
    if len(pts) <= 2:
        return np.array(pts)

    def half(seq):
        out: list = []
        for p in seq:
            while len(out) >= 2 and (
                (out[-1][0] - out[-2][0]) * (p[1] - out[-2][1]) - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])
            ) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(reversed(pts))
    return np.array(lower[:-1] + upper[:-1])


def _polygon_area(hull: np.ndarray) -> float:
    if len(hull) < 3:
        return 0.0
    x, y = hull[:, 0], hull[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _inside_hull(px: np.ndarray, hull: np.ndarray, margin: float) -> np.ndarray:
    """Pixels (..., 2) inside a convex polygon grown by ``margin`` pixels."""
    if len(hull) < 3:
        return np.zeros(px.shape[:-1], dtype=bool)
    a, b = hull, np.roll(hull, -1, axis=0)
    edge = b - a
    length = np.maximum(np.linalg.norm(edge, axis=1), 1e-12)
    rel = px[..., None, :] - a
    # pixel rows grow downward, so a counter-clockwise hull in (col, row) has its
    # interior on the side where the cross product is positive
    cross = (edge[:, 0] * rel[..., 1] - edge[:, 1] * rel[..., 0]) / length
    sign = 1.0 if _signed_area(hull) > 0 else -1.0
    return np.all(sign * cross >= -margin, axis=-1)


def _signed_area(hull: np.ndarray) -> float:
    x, y = hull[:, 0], hull[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _hand_parts(palm_pose, joint_poses, keypoints) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World capsules (starts (k, 3), ends (k, 3), radii (k,)) and palm box corners (8, 3)."""
    palm = np.asarray(palm_pose, dtype=np.float64)
    joints = np.asarray(joint_poses, dtype=np.float64).reshape(5, 3, 6)[:, :, :3]
    tips = np.asarray(keypoints, dtype=np.float64).reshape(6, 6)[:5, :3]
    rot = euler_to_matrix(palm[3:])
    chain = np.concatenate([joints, tips[:, None]], axis=1)  # (5, 4, 3)
    wrist = palm[:3] + np.outer(_WRIST_SPAN, rot[:, 2])
    starts = np.vstack([chain[:, :3].reshape(15, 3), wrist[:1]])
    ends = np.vstack([chain[:, 1:].reshape(15, 3), wrist[1:]])
    radii = np.append(np.repeat(FINGER_RADII, 3), _WRIST_RADIUS)
    corners = palm[:3] + (_BOX_SIGNS * np.asarray(PALM_HALF_EXTENTS)) @ rot.T
    return starts, ends, radii, corners


def _window(lo: np.ndarray, hi: np.ndarray, width: int, height: int):
    """Pixel window (rows slice, cols slice) and its pixel centres (h, w, 2), or None if empty."""
    c0, r0 = max(int(np.floor(lo[0])), 0), max(int(np.floor(lo[1])), 0)
    c1, r1 = min(int(np.ceil(hi[0])) + 1, width), min(int(np.ceil(hi[1])) + 1, height)
    if c0 >= c1 or r0 >= r1:
        return None
    cols, rows = np.meshgrid(np.arange(c0, c1) + 0.5, np.arange(r0, r1) + 0.5)
    return (slice(r0, r1), slice(c0, c1)), np.stack([cols, rows], axis=-1)


def hand_mask(
    palm_pose: np.ndarray, joint_poses: np.ndarray, keypoints: np.ndarray, width: int, height: int,
    margin: float = HAND_MARGIN_PX,
) -> np.ndarray:
    """(H, W) bool: the pixels the hand covers, predicted from its state and geometry
    (palm box, wrist cylinder, finger capsules), grown by ``margin`` pixels."""
    starts, ends, radii, corners = _hand_parts(palm_pose, joint_poses, keypoints)
    pa, da = project(starts, width, height)
    pb, db = project(ends, width, height)
    pc, _ = project(corners, width, height)
    r_px = radii * focal_px(height) / np.maximum(np.minimum(da, db), 1e-6) + margin
    mask = np.zeros((height, width), dtype=bool)
    for a, b, r in zip(pa, pb, r_px):
        win = _window(np.minimum(a, b) - r, np.maximum(a, b) + r, width, height)
        if win is None:
            continue
        (rows, cols), px = win
        ab = b - a
        rel = px - a
        s = np.clip((rel @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        d = rel - s[..., None] * ab
        mask[rows, cols] |= (d[..., 0] ** 2 + d[..., 1] ** 2) <= r * r
    hull = _convex_hull(pc)
    win = _window(pc.min(axis=0) - margin, pc.max(axis=0) + margin, width, height)
    if win is not None:
        (rows, cols), px = win
        mask[rows, cols] |= _inside_hull(px, hull, margin)
    return mask


def silhouette_area(category: ObjectCategory, size: float, centre_xz: np.ndarray, width: int, height: int) -> float:
    """Predicted pixel area of the category's silhouette at ``size`` resting at ``centre_xz``.

    Lying cylinders average over headings (their heading follows the unknown path).
    """
    dims = category.scaled_dims(size)
    centre = np.array([centre_xz[0], category.half_height(size), centre_xz[1]])
    ring = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    if category.shape == "sphere":
        u, v = np.meshgrid(np.linspace(0.0, np.pi, 12), ring)
        local = dims[0] * np.stack([np.sin(u) * np.cos(v), np.cos(u), np.sin(u) * np.sin(v)], axis=-1).reshape(-1, 3)
        shapes = [local]
    elif category.shape == "cylinder":
        r, length = dims
        disc = np.stack([r * np.cos(ring), r * np.sin(ring)], axis=-1)
        if category.lying:
            shapes = []
            for heading in np.linspace(0.0, np.pi, 6, endpoint=False):
                axis = np.array([np.cos(heading), 0.0, np.sin(heading)])
                side = np.cross(axis, [0.0, 1.0, 0.0])
                rim = disc[:, :1] * side + disc[:, 1:] * np.array([0.0, 1.0, 0.0])
                shapes.append(np.vstack([rim + axis * length / 2, rim - axis * length / 2]))
        else:
            rim = np.stack([disc[:, 0], np.zeros(len(ring)), disc[:, 1]], axis=-1)
            shapes = [np.vstack([rim + [0.0, length / 2, 0.0], rim - [0.0, length / 2, 0.0]])]
    else:
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
        shapes = [signs * np.asarray(dims)]
    areas = [_polygon_area(_convex_hull(project(centre + pts, width, height)[0])) for pts in shapes]
    return float(np.mean(areas))


@dataclass(frozen=True)
class Detection:
    """The object seen in one frame: blob centroid (column, row), area (pixels),
    estimated world centre (x, y, z), and whether the hand touches the blob."""

    pixel: np.ndarray
    area: int
    position: np.ndarray
    touches_hand: bool


def find_blob(foreground: np.ndarray, hand: np.ndarray) -> Optional[tuple[np.ndarray, int, bool]]:
    """Centroid (column, row), pixel count and hand contact of the object's blob, or None."""
    candidates = foreground & ~hand
    labels, count = ndimage.label(candidates)
    if count == 0:
        return None
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    sizes[0] = 0
    best = int(np.argmax(sizes))
    if sizes[best] < MIN_BLOB_PX:
        return None
    rows, cols = np.nonzero(labels == best)
    centre = np.array([cols.mean(), rows.mean()])
    reach = 2.0 * np.sqrt(sizes[best] / np.pi) + 3.0
    keep = [best]
    for k in np.flatnonzero(sizes >= MIN_BLOB_PX):
        if k == best:
            continue
        r, c = np.nonzero(labels == k)
        if np.hypot(c.mean() - centre[0], r.mean() - centre[1]) <= reach:
            keep.append(int(k))
    blob = np.isin(labels, keep)
    rows, cols = np.nonzero(blob)
    touches = bool(np.any(ndimage.binary_dilation(blob, iterations=2) & hand))
    return np.array([cols.mean() + 0.5, rows.mean() + 0.5]), int(blob.sum()), touches


class ObjectLocator:
    """Per-episode object localisation: call :meth:`locate` on each frame in order.

    Keeps the table colour (from the first frame) and the running size estimate.
    Deterministic: the same frames give the same answers.
    """

    def __init__(self, text: str, width: int, height: Optional[int] = None):
        self.width = int(width)
        self.height = int(width if height is None else height)
        name = object_from_text(text)
        self.category: Optional[ObjectCategory] = OBJECTS[name] if name else None
        self._table_rgb: Optional[np.ndarray] = None
        self._size_samples: list[float] = []

    @property
    def size(self) -> Optional[float]:
        """The estimated object size (None when the category is unknown)."""
        if self.category is None:
            return None
        nominal = self.category.nominal_size
        if not self._size_samples:
            return nominal
        est = float(np.median(self._size_samples))
        return float(np.clip(est, SIZE_RANGE[0] * nominal, SIZE_RANGE[1] * nominal))

    @property
    def centre_height(self) -> float:
        """Estimated height of the object's centre above the table."""
        if self.category is None:
            return DEFAULT_CENTRE_HEIGHT
        return self.category.half_height(self.size)

    @property
    def top_height(self) -> float:
        """Estimated height of the object's top above the table."""
        return 2.0 * self.centre_height

    def locate(
        self, image: np.ndarray, palm_pose: np.ndarray, joint_poses: np.ndarray, keypoints: np.ndarray
    ) -> Optional[Detection]:
        """The object in ``image`` (H, W, 3 uint8), given the hand's state at that frame."""
        image = np.asarray(image)
        if self._table_rgb is None:
            self._table_rgb = table_colour(image)
        diff = np.abs(image.astype(np.int16) - self._table_rgb.astype(np.int16)).max(axis=-1)
        foreground = (diff > COLOUR_THRESHOLD) & table_region(self.width, self.height)
        hand = hand_mask(palm_pose, joint_poses, keypoints, self.width, self.height)
        found = find_blob(foreground, hand)
        if found is None:
            return None
        pixel, area, touches = found
        position = unproject_to_plane(pixel, self.width, self.height, self.centre_height)
        if not touches and self.category is not None:
            predicted = silhouette_area(self.category, self.category.nominal_size, position[[0, 2]], self.width, self.height)
            if predicted > 0:
                self._size_samples.append(self.category.nominal_size * float(np.sqrt(area / predicted)))
                position = unproject_to_plane(pixel, self.width, self.height, self.centre_height)
        return Detection(pixel, area, position, touches)
