"""The hand's own pixels, predicted from its proprioception (palm pose, joint and
fingertip positions): its parts (palm box, wrist cylinder, finger capsules) projected
with the camera model and grown by :data:`HAND_MARGIN_PX` (:mod:`pipeline.policies.perception`, step 2)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from generators.hand import FINGER_RADII, PALM_HALF_EXTENTS, WRIST_OFFSET, euler_to_matrix
from pipeline.policies.camera_model import focal_px, project

#: Extra pixels around the projected hand that count as hand (JPEG ringing, rounding).
HAND_MARGIN_PX = 2.0
#: Wrist cylinder of the hand model: radius and its extent along the palm's local Z.
WRIST_RADIUS = 0.7 * PALM_HALF_EXTENTS[0]
WRIST_SPAN = (WRIST_OFFSET[2] - 0.5, WRIST_OFFSET[2])
BOX_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)


def convex_hull(points: np.ndarray) -> np.ndarray:
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


def hull_depth(xs: np.ndarray, ys: np.ndarray, hull: np.ndarray) -> np.ndarray:
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
    sign = 1.0 if signed_area(hull) > 0 else -1.0
    across = edge[:, 0:1] * (ys[None, :] - a[:, 1:2])  # (k, h)
    along = edge[:, 1:2] * (xs[None, :] - a[:, 0:1])  # (k, w)
    cross = (across[:, :, None] - along[:, None, :]) / length[:, None, None]
    return (sign * cross).min(axis=0)


def signed_area(hull: np.ndarray) -> float:
    x, y = hull[:, 0], hull[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def hand_parts(palm_pose, joint_poses, keypoints) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World capsules (starts (k, 3), ends (k, 3), radii (k,)) and palm box corners (8, 3)."""
    palm = np.asarray(palm_pose, dtype=np.float64)
    joints = np.asarray(joint_poses, dtype=np.float64).reshape(5, 3, 6)[:, :, :3]
    tips = np.asarray(keypoints, dtype=np.float64).reshape(6, 6)[:5, :3]
    rot = euler_to_matrix(palm[3:])
    chain = np.concatenate([joints, tips[:, None]], axis=1)  # (5, 4, 3)
    wrist = palm[:3] + np.outer(WRIST_SPAN, rot[:, 2])
    starts = np.vstack([chain[:, :3].reshape(15, 3), wrist[:1]])
    ends = np.vstack([chain[:, 1:].reshape(15, 3), wrist[1:]])
    radii = np.append(np.repeat(FINGER_RADII, 3), WRIST_RADIUS)
    corners = palm[:3] + (BOX_SIGNS * np.asarray(PALM_HALF_EXTENTS)) @ rot.T
    return starts, ends, radii, corners


def pixel_window(lo: np.ndarray, hi: np.ndarray, width: int, height: int):
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
        starts, ends, radii, corners = hand_parts(palm_pose, joint_poses, keypoints)
        pa, da = project(starts, width, height)
        pb, db = project(ends, width, height)
        pc, _ = project(corners, width, height)
        r_px = radii * focal_px(height) / np.maximum(np.minimum(da, db), 1e-6) + margin
        lo = np.minimum((np.minimum(pa, pb) - r_px[:, None]).min(axis=0), pc.min(axis=0) - margin)
        hi = np.maximum((np.maximum(pa, pb) + r_px[:, None]).max(axis=0), pc.max(axis=0) + margin)
        return cls(pa, pb, r_px, convex_hull(pc), margin, lo, hi)

    def mask(self, width: int, height: int, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """(H, W) bool: the hand's pixels, only inside ``window`` (row0, row1, col0, col1)."""
        mask = np.zeros((height, width), dtype=bool)
        lo, hi = self.lo, self.hi
        if window is not None:
            r0, r1, c0, c1 = window
            lo = np.maximum(lo, [c0, r0])
            hi = np.minimum(hi, [c1 - 1, r1 - 1])
        win = pixel_window(lo, hi, width, height)
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
        mask[rows, cols] = covered | (hull_depth(xs, ys, self.hull) >= -self.margin)
        return mask
