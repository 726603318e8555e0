"""The fixed egocentric camera as numpy: OpenGL-style view and projection matrices
matching pybullet's ``computeViewMatrix``/``computeProjectionMatrixFOV``, projection
of world points to pixels, and back-projection of pixels onto a horizontal plane.

Dyana's world is X right, Y up, Z forward, like the paper's Unity scene (the data
contract, docs/concepts/data-contract.md): seen from the camera, +X is on the image's
right. pybullet's camera is right-handed, so the renderer mirrors its image left-right
(``image[:, ::-1]``) and pixel columns here are measured on the mirrored image."""

from __future__ import annotations

import math

import numpy as np

from schemas.scene import (
    CAMERA_EYE,
    CAMERA_FAR,
    CAMERA_FOV_DEG,
    CAMERA_NEAR,
    CAMERA_TARGET,
    CAMERA_UP,
)


def view_matrix() -> np.ndarray:
    """4x4 world-to-camera matrix (row-major; pybullet's list is its transpose, flattened)."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (CAMERA_EYE, CAMERA_TARGET, CAMERA_UP))
    f = target - eye
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def projection_matrix(aspect: float = 1.0) -> np.ndarray:
    """4x4 OpenGL perspective matrix for the camera's vertical field of view."""
    t = 1.0 / math.tan(math.radians(CAMERA_FOV_DEG) / 2.0)
    n, f = CAMERA_NEAR, CAMERA_FAR
    return np.array(
        [
            [t / aspect, 0.0, 0.0, 0.0],
            [0.0, t, 0.0, 0.0],
            [0.0, 0.0, (f + n) / (n - f), 2.0 * f * n / (n - f)],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )


def pybullet_matrices(width: int, height: int) -> tuple[list[float], list[float]]:
    """The two matrices in pybullet's flat column-major form, for ``getCameraImage``."""
    return (
        view_matrix().T.reshape(-1).tolist(),
        projection_matrix(width / height).T.reshape(-1).tolist(),
    )


def project(points: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """World points (..., 3) -> pixel coordinates (..., 2) as (column, row) and camera depth (...)."""
    pts = np.asarray(points, dtype=np.float64)
    homo = np.concatenate([pts, np.ones(pts.shape[:-1] + (1,))], axis=-1)
    cam = homo @ view_matrix().T
    clip = cam @ projection_matrix(width / height).T
    ndc = clip[..., :3] / clip[..., 3:4]
    cols = (1.0 - ndc[..., 0]) * 0.5 * width
    rows = (1.0 - ndc[..., 1]) * 0.5 * height
    return np.stack([cols, rows], axis=-1), -cam[..., 2]


def unproject_to_plane(pixels: np.ndarray, width: int, height: int, plane_y: float) -> np.ndarray:
    """Pixels (..., 2) as (column, row) -> world points (..., 3) on the plane Y = ``plane_y``."""
    px = np.asarray(pixels, dtype=np.float64)
    ndc_x = 1.0 - px[..., 0] / width * 2.0
    ndc_y = 1.0 - px[..., 1] / height * 2.0
    proj = projection_matrix(width / height)
    dirs_cam = np.stack([ndc_x / proj[0, 0], ndc_y / proj[1, 1], -np.ones_like(ndc_x)], axis=-1)
    rot = view_matrix()[:3, :3]
    dirs = dirs_cam @ rot  # camera -> world: R^T d
    eye = np.asarray(CAMERA_EYE, dtype=np.float64)
    scale = (plane_y - eye[1]) / dirs[..., 1]
    return eye + dirs * scale[..., None]

def _camera_rows() -> tuple[tuple[float, ...], ...]:
    view = view_matrix()
    proj = projection_matrix(1.0)
    return tuple(tuple(float(v) for v in row) for row in view[:3]) + ((float(proj[0, 0]), float(proj[1, 1])),)


_CAMERA = _camera_rows()


def in_view(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Whether world points lie inside the camera's (square-image) view frustum.

    Elementwise arithmetic (no matrix product), so the answer for a point never depends
    on how many others are checked with it.
    """
    (r00, r01, r02, t0), (r10, r11, r12, t1), (r20, r21, r22, t2), (p00, p11) = _CAMERA
    cx = r00 * x + r01 * y + r02 * z + t0
    cy = r10 * x + r11 * y + r12 * z + t1
    depth = -(r20 * x + r21 * y + r22 * z + t2)
    return (
        (depth > CAMERA_NEAR)
        & (depth < CAMERA_FAR)
        & (np.abs(p00 * cx) <= depth)
        & (np.abs(p11 * cy) <= depth)
    )


def points_in_view(points: np.ndarray) -> np.ndarray:
    """(...,) whether world points (..., 3) lie inside the view frustum (see :func:`in_view`)."""
    pts = np.asarray(points, dtype=np.float64)
    return in_view(pts[..., 0], pts[..., 1], pts[..., 2])
