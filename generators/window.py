"""The screen window that holds the moving bodies, found before drawing them, and the
off-centre projection that draws only that window (the ``window`` renderer,
:mod:`schemas.renderers`).

Bounds: the 8 corners of an oriented box around each *visual* shape of the hand and the
object (``getVisualShapeData``, read once per scene: :func:`shape_boxes`), placed per
frame with their links' frames (``getLinkStates`` with forward kinematics:
:func:`world_corners`), projected with the camera's view and projection matrices in
float64 and padded by :data:`PAD` pixels (:meth:`WindowCamera.window`). (pybullet's
``getAABB`` gives collision bounds, which miss the objects, visual-only bodies, and the
hand's wrist and joint spheres.) Everything here is a function of the bodies' current
poses, so the window of a frame depends on its episode's state alone.

Projection: rows 0 and 1 of the camera's projection are scaled and translated so that
the window ``[c0, c1) x [r0, r1)`` of the unmirrored image maps onto a ``(c1 - c0) x
(r1 - r0)`` viewport (:meth:`WindowCamera.projection`); depth rows, view matrix and
lights are unchanged. TinyRenderer rounds the screen coordinates of the shifted
viewport differently, so a window draw is not bit-identical to the full-viewport draw
(``benchmarks/window_render.py`` measures by how much).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from generators.bullet import p
from generators.camera import projection_matrix, view_matrix

#: Pixels added on every side of the projected bounds (covers rasterisation rounding).
PAD = 2
#: A corner this near the camera plane (clip w) or behind it makes the window the whole image.
MIN_CLIP_W = 1e-6
_CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)

#: A window ``(r0, r1, c0, c1)`` of the unmirrored image: rows [r0, r1), columns [c0, c1).
Window = tuple[int, int, int, int]


def _half_extents(geometry: int, dims) -> np.ndarray | None:
    """Half extents of a box holding a visual shape in its own frame; None for another kind."""
    if geometry == p.GEOM_SPHERE:
        return np.full(3, float(dims[0]))
    if geometry == p.GEOM_BOX:  # reported as full extents
        return 0.5 * np.asarray(dims[:3], dtype=np.float64)
    if geometry == p.GEOM_CYLINDER:  # (length, radius), axis local Z
        return np.array([dims[1], dims[1], 0.5 * dims[0]], dtype=np.float64)
    if geometry == p.GEOM_CAPSULE:
        return np.array([dims[1], dims[1], 0.5 * dims[0] + dims[1]], dtype=np.float64)
    return None


def _rotation(quat) -> np.ndarray:
    """A quaternion (x, y, z, w) as a 3x3 rotation matrix."""
    x, y, z, w = (float(v) for v in quat)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _affine(m: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``points @ m.T + t`` for (n, 3) points, in a fixed order of IEEE operations: no BLAS, whose
    kernels (and fused multiply-adds) vary with the CPU, so the result is the same on every host."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    return np.stack([m[i, 0] * x + m[i, 1] * y + m[i, 2] * z + t[i] for i in range(m.shape[0])], axis=-1)


@dataclass(frozen=True)
class ShapeBoxes:
    """Corners of a box around every visual shape of some bodies, in their links' frames."""

    client: int
    bodies: tuple[tuple[int, tuple[int, ...]], ...]  # (body, its links holding shapes)
    frame: np.ndarray  # (corners,) which placed frame (base, then links, body by body) holds each corner
    corners: np.ndarray  # (corners, 3)


def shape_boxes(client: int, bodies: tuple[int, ...]) -> ShapeBoxes | None:
    """The boxes of ``bodies`` in ``client``; None when a shape is of a kind without a box
    (a mesh: then every frame's window is the whole image)."""
    placed, frame, corners, frames = [], [], [], 0
    for body in bodies:
        shapes = []
        for shape in p.getVisualShapeData(body, physicsClientId=client):
            link, half = shape[1], _half_extents(shape[2], shape[3])
            if half is None:
                return None
            shapes.append((link, _affine(_rotation(shape[6]), np.asarray(shape[5], dtype=np.float64), _CUBE * half)))
        links = tuple(sorted({link for link, _ in shapes if link >= 0}))
        row = {link: frames + i for i, link in enumerate((-1, *links))}
        for link, local in shapes:
            frame.append(row[link])
            corners.append(local)
        placed.append((body, links))
        frames += 1 + len(links)
    if not corners:
        return None
    return ShapeBoxes(client, tuple(placed), np.repeat(np.asarray(frame, dtype=np.intp), 8), np.concatenate(corners))


def world_corners(boxes: ShapeBoxes) -> np.ndarray:
    """(corners, 3) world positions of the boxes' corners for the bodies' current poses."""
    positions, orientations = [], []
    for body, links in boxes.bodies:
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=boxes.client)
        positions.append(pos)
        orientations.append(orn)
        if links:
            for state in p.getLinkStates(body, list(links), computeForwardKinematics=1, physicsClientId=boxes.client):
                positions.append(state[0])
                orientations.append(state[1])
    q = np.asarray(orientations, dtype=np.float64)[boxes.frame]
    t = np.asarray(positions, dtype=np.float64)[boxes.frame]
    # v rotated by q: v + w u + q x u, with u = 2 q x v (written out: np.cross costs more on small arrays)
    qx, qy, qz, qw = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    vx, vy, vz = boxes.corners[:, 0], boxes.corners[:, 1], boxes.corners[:, 2]
    ux, uy, uz = 2.0 * (qy * vz - qz * vy), 2.0 * (qz * vx - qx * vz), 2.0 * (qx * vy - qy * vx)
    out = np.empty_like(t)
    out[:, 0] = vx + qw * ux + (qy * uz - qz * uy) + t[:, 0]
    out[:, 1] = vy + qw * uy + (qz * ux - qx * uz) + t[:, 1]
    out[:, 2] = vz + qw * uz + (qx * uy - qy * ux) + t[:, 2]
    return out


@dataclass(frozen=True)
class WindowCamera:
    """The fixed camera at a ``width`` x ``height`` image: windows of world points and the
    projection that draws one."""

    width: int
    height: int
    pad: int = PAD

    @cached_property
    def projection_rows(self) -> np.ndarray:
        """The camera's 4x4 projection matrix (row-major)."""
        return projection_matrix(self.width / self.height)

    @cached_property
    def clip_matrix(self) -> np.ndarray:
        """World -> clip coordinates: projection times view (summed in a fixed order, see :func:`_affine`)."""
        a, b = self.projection_rows, view_matrix()
        return np.array([[sum(float(a[i, k]) * float(b[k, j]) for k in range(4)) for j in range(4)] for i in range(4)])

    def window(self, points: np.ndarray) -> Window | None:
        """The padded window holding every point's projection, clipped to the image; the
        whole image when a point is not in front of the camera; None when it is empty."""
        w, h, pad = self.width, self.height, self.pad
        m = self.clip_matrix
        px, py, pz = points[:, 0], points[:, 1], points[:, 2]
        cw = m[3, 0] * px + m[3, 1] * py + m[3, 2] * pz + m[3, 3]  # as _affine, rows 0, 1 and 3 only
        if np.any(cw <= MIN_CLIP_W):
            return 0, h, 0, w
        # TinyRenderer samples pixel P at screen (w/2 (ndc_x + 1), h/2 (ndc_y + 1)); image row h - 1 - P.y
        x = 0.5 * w * ((m[0, 0] * px + m[0, 1] * py + m[0, 2] * pz + m[0, 3]) / cw + 1.0)
        y = 0.5 * h * ((m[1, 0] * px + m[1, 1] * py + m[1, 2] * pz + m[1, 3]) / cw + 1.0)
        c0 = max(0, math.floor(float(x.min())) - pad)
        c1 = min(w, math.ceil(float(x.max())) + 1 + pad)
        r0 = max(0, h - 1 - math.ceil(float(y.max())) - pad)
        r1 = min(h, h - math.floor(float(y.min())) + pad)
        if c0 >= c1 or r0 >= r1:
            return None
        return r0, r1, c0, c1

    def projection(self, window: Window) -> list[float]:
        """pybullet's flat projection matrix that maps ``window`` onto its own viewport (the
        camera's own matrix for the whole image)."""
        r0, r1, c0, c1 = window
        full = self.projection_rows
        w, h, y0 = c1 - c0, r1 - r0, self.height - r1
        m = full.copy()
        m[0] = (self.width / w) * full[0] + ((self.width - 2.0 * c0) / w - 1.0) * full[3]
        m[1] = (self.height / h) * full[1] + ((self.height - 2.0 * y0) / h - 1.0) * full[3]
        return m.T.reshape(-1).tolist()
