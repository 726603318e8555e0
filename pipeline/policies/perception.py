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

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from pipeline.policies.camera_model import table_colour, table_region, unproject
from pipeline.policies.hand_shape import HandShape
from pipeline.policies.silhouette import headings, match_template, template
from schemas.objects import OBJECTS, ObjectCategory

#: A pixel is foreground when its RGB distance to the table's colour is larger (the
#: table's JPEG noise stays under 15; the darkest shades of the blue and green objects
#: are 25-40 away).
COLOUR_THRESHOLD = 22
#: Components smaller than this many pixels are noise.
MIN_BLOB_PX = 4
#: Assumed centre height (units) when the text names no known category.
DEFAULT_CENTRE_HEIGHT = 0.4
#: Estimated sizes are kept within this factor range of the category's nominal size.
SIZE_RANGE = (0.7, 1.3)
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
        return None if self.category is None else self.estimated_size(self.category)

    def estimated_size(self, category: ObjectCategory) -> float:
        """The median of the size samples within :data:`SIZE_RANGE` of the category's
        nominal size (the nominal size before any sample)."""
        if self._size is None:  # computed once per new sample: every template needs it
            nominal = category.nominal_size
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
        return self.category.half_height(self.estimated_size(self.category))

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
        first = unproject(centroid, self.width, self.height, self.centre_height)
        if self.category is None:
            self._last_pixel = centroid
            return Detection(centroid, first, area, 1.0, touches, 0.0)

        background = region & ~foreground & ~hand_crop
        size = self.estimated_size(self.category)
        options = headings(self.category)
        tried: Sequence[int] = range(len(options))
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
        position = unproject(pixel, self.width, self.height, self.centre_height)
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
