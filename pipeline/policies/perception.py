"""Where is the object? Localisation from one RGB frame, with public knowledge only.

A policy sees pixels, its own hand's state and the task text. What it may know
besides (the benchmark is public): the fixed camera (:mod:`generators.camera`), the
table's extent and its colour, the hand's geometry, and the object categories'
shapes (the text names the category). What it may not know: the object's size, hence
its height above the table, and where it is.

The recipe, per frame:

1. *Foreground*: pixels on the table top whose RGB distance to the table's colour
   exceeds :data:`COLOUR_THRESHOLD` (the colour is measured once per episode, as the
   median of the table region, which the object and hand barely cover). After a
   sighting only a window around it is searched (:data:`ROI_HALF_PX`).
2. *Hand*: the hand's own pixels are predicted from its proprioception (palm pose,
   joint and fingertip positions) by projecting its parts (palm box, wrist cylinder,
   finger capsules) with the camera model, grown by a margin for JPEG's ringing, and
   removed.
3. *Blob*: the largest connected foreground component left, with the components
   near it (a finger lying across the object splits it).
4. *Silhouette match*: the category's silhouette at the estimated size (the
   projected convex hull of its shape; six headings for a lying cylinder, whose
   heading follows its unknown path), grown by JPEG's one-pixel halo, is slid over the
   blob. The best shift minimises template pixels over clearly visible table plus
   blob pixels outside the template; pixels under the hand cost nothing, so a partly
   hidden object is still placed by what shows. For a blob clear of the hand, its
   centroid refines the match to a fraction of a pixel.
5. *Back-projection*: the matched centre pixel's viewing ray meets the horizontal
   plane at the object's centre height (the category's resting half height at the
   estimated size).

The size is estimated from blobs clear of the hand: the blob's area (its JPEG-blended
rim weighted by colour, :func:`weighted_area`) over the silhouette's, times the size
the silhouette was drawn at, square-rooted; the median of these samples. Until one
exists the category's nominal size is assumed. If the text names no known category,
the blob's centroid is back-projected at :data:`DEFAULT_CENTRE_HEIGHT`.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from generators.camera import projection_matrix, unproject_to_plane, view_matrix
from generators.hand import (
    FINGER_RADII,
    PALM_HALF_EXTENTS,
    WRIST_OFFSET,
    euler_to_matrix,
)
from generators.scene import TABLE_BORDER
from schemas.objects import OBJECTS, ObjectCategory
from schemas.scene import CAMERA_EYE, CAMERA_FOV_DEG, TABLE_X, TABLE_Z

#: A pixel is foreground when its RGB distance to the table's colour is larger (the
#: table's JPEG noise stays under 15; the darkest shades of the blue and green objects
#: are 25-40 away).
COLOUR_THRESHOLD = 22
#: Extra pixels around the projected hand that count as hand (JPEG ringing, rounding).
HAND_MARGIN_PX = 2.0
#: Silhouette templates are grown by this many pixels to match JPEG's halo.
HALO_PX = 1.0
#: Components smaller than this many pixels are noise.
MIN_BLOB_PX = 4
#: Assumed centre height (units) when the text names no known category.
DEFAULT_CENTRE_HEIGHT = 0.4
#: Estimated sizes are kept within this factor range of the category's nominal size.
SIZE_RANGE = (0.7, 1.3)
#: Wrist cylinder of the hand model: radius and its extent along the palm's local Z.
_WRIST_RADIUS = 0.7 * PALM_HALF_EXTENTS[0]
_WRIST_SPAN = (WRIST_OFFSET[2] - 0.5, WRIST_OFFSET[2])
_BOX_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
_NEIGHBOURS = np.array([[dr, dc] for dr in (-2, -1, 0, 1, 2) for dc in (-2, -1, 0, 1, 2)])
#: Template search reach (pixels) around a clean blob, and the most it may reach when occluded.
CLEAN_REACH_PX = 3
MAX_REACH_PX = 20
#: A lying cylinder's heading is tracked from frames showing at least this share of it.
HEADING_COVERAGE = 0.5
#: After a sighting, the next frame is searched this far around it (pixels at 224 px).
ROI_HALF_PX = 48
#: Sub-pixel centroid corrections larger than this are not trusted.
MAX_CENTROID_CORRECTION_PX = 2.0


def object_from_text(text: str) -> str | None:
    """The object category the task text names (the longest matching name), or None."""
    lowered = " ".join(re.findall(r"[a-z]+", str(text).lower()))
    found = [name for name in OBJECTS if re.search(rf"\b{name.replace('_', ' ')}\b", lowered)]
    return max(found, key=len) if found else None


@functools.lru_cache(maxsize=8)
def _clip_from_world(width: int, height: int) -> np.ndarray:
    return projection_matrix(width / height) @ view_matrix()


def _project(points: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`generators.camera.project` with the matrices computed once per resolution:
    pixels (..., 2) as (column, row) and the clip w (the camera depth)."""
    pts = np.asarray(points, dtype=np.float64)
    m = _clip_from_world(width, height)
    clip = pts @ m[:, :3].T + m[:, 3]
    w = clip[..., 3:4]
    cols = (1.0 - clip[..., 0:1] / w) * 0.5 * width
    rows = (1.0 - clip[..., 1:2] / w) * 0.5 * height
    return np.concatenate([cols, rows], axis=-1), w[..., 0]


@functools.lru_cache(maxsize=8)
def _unprojection(width: int, height: int) -> tuple[float, float, np.ndarray, np.ndarray]:
    """The constants :func:`generators.camera.unproject_to_plane` recomputes per call."""
    proj = projection_matrix(width / height)
    rot = view_matrix()[:3, :3]
    rot.setflags(write=False)
    eye = np.asarray(CAMERA_EYE, dtype=np.float64)
    eye.setflags(write=False)
    return float(proj[0, 0]), float(proj[1, 1]), rot, eye


def _unproject(pixels: np.ndarray, width: int, height: int, plane_y: float) -> np.ndarray:
    """:func:`generators.camera.unproject_to_plane` with its matrices computed once per
    resolution (the same operations in the same order, so the same bits)."""
    px = np.asarray(pixels, dtype=np.float64)
    ndc_x = 1.0 - px[..., 0] / width * 2.0
    ndc_y = 1.0 - px[..., 1] / height * 2.0
    p00, p11, rot, eye = _unprojection(width, height)
    dirs = np.stack([ndc_x / p00, ndc_y / p11, -np.ones_like(ndc_x)], axis=-1) @ rot
    scale = (plane_y - eye[1]) / dirs[..., 1]
    return eye + dirs * scale[..., None]


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
    # rays above the horizon meet the plane behind the camera (z < eye z), off the table
    return ndimage.binary_erosion(inside, iterations=1)


def table_colour(image: np.ndarray) -> np.ndarray:
    """(3,) median RGB of the table region of ``image``: the table's rendered colour."""
    h, w = image.shape[:2]
    return np.median(image[table_region(w, h)], axis=0)


def _convex_hull(points: np.ndarray) -> np.ndarray:
    """Convex hull vertices (k, 2) of 2D points (m, 2), counterclockwise (positive signed
    area), without collinear or repeated points; empty if degenerate (fewer than 3).

    Andrew's monotone chain on the points' own coordinates: the vertices and their
    orientation are Qhull's (``scipy.spatial.ConvexHull``, which this replaced), at a
    fraction of a call's cost, which perception pays for every template.
    """
    pts = np.asarray(points, dtype=np.float64)
    order = np.lexsort((pts[:, 1], pts[:, 0]))
    xy = pts[order].tolist()

    def chain(sequence: Iterable[list[float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for x, y in sequence:
            while len(out) >= 2:
                (ax, ay), (bx, by) = out[-2], out[-1]
                if (bx - ax) * (y - ay) - (by - ay) * (x - ax) > 0.0:
                    break
                out.pop()
            out.append((x, y))
        return out

    lower, upper = chain(xy), chain(reversed(xy))
    hull = lower[:-1] + upper[:-1]
    if len(hull) < 3:
        return np.empty((0, 2))
    return np.array(hull, dtype=np.float64)


def _hull_depth(xs: np.ndarray, ys: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """(h, w): how far (pixels) each pixel centre of the grid ``xs`` (w,) x ``ys`` (h,)
    lies inside the nearest edge of a convex polygon: a pixel is inside the polygon
    grown by ``m`` pixels when this is >= -m (-inf everywhere for a degenerate hull)."""
    if len(hull) < 3:
        return np.full((len(ys), len(xs)), -np.inf)
    a, b = hull, np.roll(hull, -1, axis=0)
    edge = b - a
    length = np.maximum(np.linalg.norm(edge, axis=1), 1e-12)
    # the interior lies on the side of every edge that the hull's orientation gives; the
    # cross product edge x (pixel - a) splits into a row term and a column term
    sign = 1.0 if _signed_area(hull) > 0 else -1.0
    across = edge[:, 0:1] * (ys[None, :] - a[:, 1:2])  # (k, h)
    along = edge[:, 1:2] * (xs[None, :] - a[:, 0:1])  # (k, w)
    cross = (across[:, :, None] - along[:, None, :]) / length[:, None, None]
    return (sign * cross).min(axis=0)


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
    """Pixel window (rows slice, cols slice) and its pixel centres' columns (w,) and rows
    (h,), or None if empty."""
    c0, r0 = max(int(np.floor(lo[0])), 0), max(int(np.floor(lo[1])), 0)
    c1, r1 = min(int(np.ceil(hi[0])) + 1, width), min(int(np.ceil(hi[1])) + 1, height)
    if c0 >= c1 or r0 >= r1:
        return None
    return (slice(r0, r1), slice(c0, c1)), np.arange(c0, c1) + 0.5, np.arange(r0, r1) + 0.5


def hand_mask(
    palm_pose: np.ndarray, joint_poses: np.ndarray, keypoints: np.ndarray, width: int, height: int,
    margin: float = HAND_MARGIN_PX, window: tuple[int, int, int, int] | None = None,
) -> np.ndarray:
    """(H, W) bool: the pixels the hand covers, predicted from its state and geometry
    (palm box, wrist cylinder, finger capsules), grown by ``margin`` pixels; only
    inside ``window`` (row0, row1, col0, col1) when given."""
    shape = HandShape.of(palm_pose, joint_poses, keypoints, width, height, margin)
    return shape.mask(width, height, window)


@dataclass(frozen=True)
class HandShape:
    """The hand projected into the image: finger and wrist capsules from ``starts`` to
    ``ends`` (k, 2 pixels) with radii ``radii`` (k,), the palm box's convex hull, and the
    bounding box ``lo``-``hi`` (column, row) of everything, all grown by ``margin``.
    One state gives one shape, so the frames of an observe window (the hand at rest)
    project it once; :meth:`mask` draws it inside any window, pixel by pixel the same."""

    starts: np.ndarray
    ends: np.ndarray
    radii: np.ndarray
    hull: np.ndarray
    margin: float
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(
        cls, palm_pose: np.ndarray, joint_poses: np.ndarray, keypoints: np.ndarray, width: int, height: int,
        margin: float = HAND_MARGIN_PX,
    ) -> HandShape:
        starts, ends, radii, corners = _hand_parts(palm_pose, joint_poses, keypoints)
        pa, da = _project(starts, width, height)
        pb, db = _project(ends, width, height)
        pc, _ = _project(corners, width, height)
        r_px = radii * focal_px(height) / np.maximum(np.minimum(da, db), 1e-6) + margin
        lo = np.minimum((np.minimum(pa, pb) - r_px[:, None]).min(axis=0), pc.min(axis=0) - margin)
        hi = np.maximum((np.maximum(pa, pb) + r_px[:, None]).max(axis=0), pc.max(axis=0) + margin)
        return cls(pa, pb, r_px, _convex_hull(pc), margin, lo, hi)

    def mask(self, width: int, height: int, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """(H, W) bool: the hand's pixels, only inside ``window`` (row0, row1, col0, col1)."""
        mask = np.zeros((height, width), dtype=bool)
        lo, hi = self.lo, self.hi
        if window is not None:
            r0, r1, c0, c1 = window
            lo = np.maximum(lo, [c0, r0])
            hi = np.minimum(hi, [c1 - 1, r1 - 1])
        win = _window(lo, hi, width, height)
        if win is None:
            return mask
        (rows, cols), xs, ys = win
        pa, pb, r_px = self.starts, self.ends, self.radii
        x, y = xs[None, :, None], ys[:, None, None]  # (h, w, 1) against the k capsules
        ab = pb - pa
        rx, ry = x - pa[:, 0], y - pa[:, 1]
        s = np.clip((rx * ab[:, 0] + ry * ab[:, 1]) / np.maximum((ab * ab).sum(axis=1), 1e-12), 0.0, 1.0)
        dx, dy = rx - s * ab[:, 0], ry - s * ab[:, 1]
        covered = np.any(dx * dx + dy * dy <= r_px * r_px, axis=-1)
        mask[rows, cols] = covered | (_hull_depth(xs, ys, self.hull) >= -self.margin)
        return mask


@functools.lru_cache(maxsize=256)
def _surface_points(category: ObjectCategory, size: float, heading: float) -> np.ndarray:
    """Points (m, 3) whose convex hull is the object's body at ``size``, centre at the origin
    (read-only: cached, as a window's frames share size and heading).

    ``heading`` turns a lying cylinder's axis in the XZ plane; other shapes ignore it
    (non-rolling objects keep their orientation; a sphere looks the same any way).
    """
    points = _body_points(category, size, heading)
    points.setflags(write=False)
    return points


def _body_points(category: ObjectCategory, size: float, heading: float) -> np.ndarray:
    dims = category.scaled_dims(size)
    ring = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    if category.shape == "sphere":
        u, v = np.meshgrid(np.linspace(0.0, np.pi, 9), ring)
        return dims[0] * np.stack([np.sin(u) * np.cos(v), np.cos(u), np.sin(u) * np.sin(v)], axis=-1).reshape(-1, 3)
    if category.shape == "cylinder":
        r, length = dims
        if category.lying:
            axis = np.array([np.cos(heading), 0.0, np.sin(heading)])
            side = np.cross(axis, [0.0, 1.0, 0.0])
            rim = np.outer(r * np.cos(ring), side) + np.outer(r * np.sin(ring), [0.0, 1.0, 0.0])
            return np.vstack([rim + axis * length / 2, rim - axis * length / 2])
        rim = np.stack([r * np.cos(ring), np.zeros(len(ring)), r * np.sin(ring)], axis=-1)
        return np.vstack([rim + [0.0, length / 2, 0.0], rim - [0.0, length / 2, 0.0]])
    return _BOX_SIGNS * np.asarray(dims)


def headings(category: ObjectCategory) -> tuple[float, ...]:
    """The orientations a template search tries: six headings for lying cylinders."""
    if category.shape == "cylinder" and category.lying:
        return tuple(np.linspace(0.0, np.pi, 6, endpoint=False))
    return (0.0,)


@dataclass(frozen=True)
class Template:
    """A predicted silhouette: mask (h, w) whose top-left pixel is ``origin`` (row, col),
    the projected object centre ``centre`` (column, row) and the silhouette's pixel count."""

    mask: np.ndarray
    origin: tuple[int, int]
    centre: np.ndarray
    area: int


def template(
    category: ObjectCategory, size: float, centre_xz: np.ndarray, heading: float, width: int, height: int
) -> Template | None:
    """The silhouette of the object resting at ``centre_xz``, rasterised and grown by
    :data:`HALO_PX` (JPEG's halo around every edge, which the blob includes), or None
    if off-image. ``area`` counts the silhouette itself."""
    centre = np.array([centre_xz[0], category.half_height(size), centre_xz[1]])
    px, _ = _project(centre + _surface_points(category, size, heading), width, height)
    hull = _convex_hull(px)
    win = _window(px.min(axis=0) - HALO_PX, px.max(axis=0) + HALO_PX, width, height)
    if win is None:
        return None
    (rows, cols), xs, ys = win
    depth = _hull_depth(xs, ys, hull)
    mask = depth >= -HALO_PX
    area = int(np.count_nonzero(depth >= 0.0))
    if area == 0:
        return None
    return Template(mask, (rows.start, cols.start), _project(centre, width, height)[0], area)


def _crop(image: np.ndarray, r0: int, c0: int, h: int, w: int) -> np.ndarray:
    """``image[r0:r0+h, c0:c0+w]`` as int64, zero outside the image."""
    out = np.zeros((h, w), dtype=np.int64)
    rr0, cc0 = max(r0, 0), max(c0, 0)
    rr1, cc1 = min(r0 + h, image.shape[0]), min(c0 + w, image.shape[1])
    if rr0 < rr1 and cc0 < cc1:
        out[rr0 - r0 : rr1 - r0, cc0 - c0 : cc1 - c0] = image[rr0:rr1, cc0:cc1]
    return out


def _correlate(images: np.ndarray, tpl: Template, reach: int, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Overlap counts (k, 2 reach + 1, 2 reach + 1) of each image (k, H, W) with the
    template shifted by (row, col) offsets in [-reach, reach]; exact integers (FFT,
    rounded). The images' top-left pixel is ``origin`` (row, col) of the frame, and
    they are taken as zero outside."""
    h, w = tpl.mask.shape
    r0, c0 = tpl.origin[0] - origin[0], tpl.origin[1] - origin[1]
    crops = np.stack([_crop(image, r0 - reach, c0 - reach, h + 2 * reach, w + 2 * reach) for image in images])
    shape = crops.shape[1:]
    spectrum = np.fft.rfft2(crops, s=shape) * np.conj(np.fft.rfft2(tpl.mask.astype(np.float64), s=shape))
    full = np.fft.irfft2(spectrum, s=shape)
    return np.rint(full[:, : 2 * reach + 1, : 2 * reach + 1]).astype(np.int64)


def match_template(
    tpl: Template, blob: np.ndarray, background: np.ndarray, reach: int, origin: tuple[int, int] = (0, 0)
) -> tuple[np.ndarray, int]:
    """Best shift (column, row) of the template and its mismatch.

    Mismatch = template pixels over clearly visible table + blob pixels outside the
    template; pixels the hand covers cost nothing (the object may be behind it).
    Several equally good shifts (an object mostly hidden) are averaged. ``blob`` and
    ``background`` may be a crop of the frame whose top-left pixel is ``origin`` (row,
    col), empty outside it.
    """
    on_background, on_blob = _correlate(np.stack([background, blob]), tpl, reach, origin)
    score = on_background + int(blob.sum()) - on_blob
    best = int(score.min())
    rows, cols = np.nonzero(score == best)
    return np.array([cols.mean() - reach, rows.mean() - reach]), best


@dataclass(frozen=True)
class Detection:
    """The object seen in one frame.

    ``pixel`` the estimated image position (column, row) of the object's centre,
    ``position`` the world centre (x, y, z) it back-projects to, ``area`` the blob's
    area in pixels (:func:`weighted_area`), ``coverage`` that over the predicted
    silhouette's (small when the hand hides the object), ``touches_hand`` whether the
    blob borders the hand, and
    ``mismatch`` the template mismatch over the silhouette's area (0 = perfect).
    """

    pixel: np.ndarray
    position: np.ndarray
    area: float
    coverage: float
    touches_hand: bool
    mismatch: float


def find_blob(foreground: np.ndarray, hand: np.ndarray) -> np.ndarray | None:
    """(H, W) bool mask of the object's blob: the largest component of the foreground
    outside the hand, with the components near it; None when nothing is left."""
    labels, count = ndimage.label(foreground & ~hand)
    if count == 0:
        return None
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    sizes[0] = 0
    best = int(np.argmax(sizes))
    if sizes[best] < MIN_BLOB_PX:
        return None
    objects = ndimage.find_objects(labels)
    centres = np.array([[(s[1].start + s[1].stop) / 2.0, (s[0].start + s[0].stop) / 2.0] for s in objects])
    reach = 2.0 * np.sqrt(sizes[best] / np.pi) + 3.0
    near = np.hypot(*(centres - centres[best - 1]).T) <= reach
    keep = np.flatnonzero(near & (sizes[1:] >= MIN_BLOB_PX)) + 1
    return np.isin(labels, keep)


def weighted_area(blob: np.ndarray, distance2: np.ndarray) -> float:
    """The blob's area with its rim weighted by how far each rim pixel's colour is from
    the table's, relative to the blob's interior: JPEG smears every edge into a halo of
    blended pixels, which would otherwise inflate the area by up to a third."""
    rows, cols = np.nonzero(blob)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    crop = blob[r0:r1, c0:c1]
    inner = ndimage.binary_erosion(crop)
    if inner.sum() < MIN_BLOB_PX:
        return float(crop.sum())
    distance = np.sqrt(distance2[r0:r1, c0:c1].astype(np.float64))
    span = max(float(np.median(distance[inner])), 1.0)
    rim = crop & ~inner
    return float(inner.sum() + np.clip(distance[rim] / span, 0.0, 1.0).sum())


def _centroid(mask: np.ndarray, r0: int = 0, c0: int = 0) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    return np.array([cols.mean() + c0 + 0.5, rows.mean() + r0 + 0.5])


class ObjectLocator:
    """Per-episode object localisation: call :meth:`locate` on each frame in order.

    Keeps the table colour (from the first frame) and the running size estimate.
    Deterministic: the same frames give the same answers.
    """

    def __init__(self, text: str, width: int, height: int | None = None):
        self.width = int(width)
        self.height = int(width if height is None else height)
        name = object_from_text(text)
        self.category: ObjectCategory | None = OBJECTS[name] if name else None
        self._table_rgb: np.ndarray | None = None
        self._squares: list[np.ndarray] = []
        self._heading: int | None = None
        self._last_pixel: np.ndarray | None = None
        self._size_samples: list[float] = []
        self._size: float | None = None
        self._hand: tuple[bytes, HandShape] | None = None

    @property
    def size(self) -> float | None:
        """The estimated object size (None when the category is unknown)."""
        if self.category is None:
            return None
        if self._size is None:  # computed once per new sample: every template needs it
            nominal = self.category.nominal_size
            if not self._size_samples:
                self._size = nominal
            else:
                est = float(np.median(self._size_samples))
                self._size = float(np.clip(est, SIZE_RANGE[0] * nominal, SIZE_RANGE[1] * nominal))
        return self._size

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
    ) -> Detection | None:
        """The object in ``image`` (H, W, 3 uint8), given the hand's state at that frame.

        Only the search window (:meth:`_roi`) is examined, so the masks below are crops
        of the frame whose top-left pixel is ``(r0, c0)``; the frame outside is empty.
        """
        image = np.asarray(image)
        if self._table_rgb is None:
            self._table_rgb = table_colour(image)
            levels = np.arange(256)
            self._squares = [((levels - c) ** 2).astype(np.int32) for c in self._table_rgb]
        r0, r1, c0, c1 = window = self._roi()
        region = table_region(self.width, self.height)[r0:r1, c0:c1]
        sq = self._squares
        crop = image[r0:r1, c0:c1]
        distance2 = np.take(sq[0], crop[..., 0]) + np.take(sq[1], crop[..., 1]) + np.take(sq[2], crop[..., 2])
        foreground = (distance2 > COLOUR_THRESHOLD**2) & region
        hand = self._hand_shape(palm_pose, joint_poses, keypoints).mask(self.width, self.height, window)
        hand_crop = hand[r0:r1, c0:c1]
        blob = find_blob(foreground, hand_crop)
        if blob is None:
            self._last_pixel = None
            return None
        area = weighted_area(blob, distance2)
        rows, cols = np.nonzero(blob)
        rows, cols = rows + r0, cols + c0
        # the hand is drawn inside the window only: without a hand pixel there, nothing touches it
        touches = bool(hand_crop.any()) and bool(
            np.any(hand[np.clip(rows[:, None] + _NEIGHBOURS[:, 0], 0, self.height - 1),
                        np.clip(cols[:, None] + _NEIGHBOURS[:, 1], 0, self.width - 1)])
        )
        centroid = np.array([cols.mean() + 0.5, rows.mean() + 0.5])
        first = _unproject(centroid, self.width, self.height, self.centre_height)
        if self.category is None:
            self._last_pixel = centroid
            return Detection(centroid, first, area, 1.0, touches, 0.0)

        background = region & ~foreground & ~hand_crop
        size = self.size
        options = headings(self.category)
        tried = range(len(options))
        if self._heading is not None and len(options) > 2:
            tried = [(self._heading + d) % len(options) for d in (-1, 0, 1)]
        best = None
        for index in tried:
            tpl = template(self.category, size, first[[0, 2]], options[index], self.width, self.height)
            if tpl is None:
                continue
            reach = CLEAN_REACH_PX
            if touches:
                reach = int(min(np.ceil(np.hypot(*tpl.mask.shape) / 2) + 2, MAX_REACH_PX))
            shift, miss = match_template(tpl, blob, background, reach, (r0, c0))
            if best is None or miss < best[2]:
                best = (tpl, shift, miss, index)
        if best is None:
            self._last_pixel = centroid
            return Detection(centroid, first, area, 1.0, touches, 0.0)
        tpl, shift, miss, index = best
        if not touches or area >= HEADING_COVERAGE * tpl.area:
            self._heading = index
        pixel = tpl.centre + shift
        if not touches:
            # sub-pixel: the blob's centroid against the shifted template's
            offset = np.rint(shift[::-1]).astype(int)
            placed = _centroid(tpl.mask, tpl.origin[0] + offset[0], tpl.origin[1] + offset[1])
            delta = centroid - placed
            if np.hypot(*delta) <= MAX_CENTROID_CORRECTION_PX:
                pixel = tpl.centre + offset[::-1] + delta
            self._size_samples.append(size * float(np.sqrt(area / tpl.area)))
            self._size = None
        position = _unproject(pixel, self.width, self.height, self.centre_height)
        self._last_pixel = pixel
        return Detection(pixel, position, area, area / tpl.area, touches, miss / tpl.area)

    def _hand_shape(self, palm_pose: np.ndarray, joint_poses: np.ndarray, keypoints: np.ndarray) -> HandShape:
        """The hand's :class:`HandShape`, projected once per state (an observe window's
        frames all show the resting hand of the first observation)."""
        palm, joints, keys = (np.asarray(a) for a in (palm_pose, joint_poses, keypoints))
        key = b"|".join(a.dtype.str.encode() + repr(a.shape).encode() + a.tobytes() for a in (palm, joints, keys))
        if self._hand is None or self._hand[0] != key:
            self._hand = (key, HandShape.of(palm, joints, keys, self.width, self.height))
        return self._hand[1]

    def _roi(self) -> tuple[int, int, int, int]:
        """Rows and columns to search: around the last sighting, else the whole image."""
        if self._last_pixel is None:
            return 0, self.height, 0, self.width
        c, r = (int(round(v)) for v in self._last_pixel)
        half = ROI_HALF_PX * self.height // 224 + 1
        return max(r - half, 0), min(r + half, self.height), max(c - half, 0), min(c + half, self.width)
