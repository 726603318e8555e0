"""The fixed camera as a policy may model it (public knowledge: :mod:`generators.camera`):
projection of world points to pixels, back-projection of pixels onto a horizontal
plane, and the table's region and colour in the image (:mod:`pipeline.policies.perception`)."""

from __future__ import annotations

import functools

import numpy as np
from scipy import ndimage

from generators.camera import projection_matrix, unproject_to_plane, view_matrix
from generators.scene import TABLE_BORDER
from schemas.scene import CAMERA_EYE, CAMERA_FOV_DEG, TABLE_X, TABLE_Z


@functools.lru_cache(maxsize=8)
def clip_from_world(width: int, height: int) -> np.ndarray:
    return projection_matrix(width / height) @ view_matrix()


def project(points: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`generators.camera.project` with the matrices computed once per resolution:
    pixels (..., 2) as (column, row) and the clip w (the camera depth)."""
    pts = np.asarray(points, dtype=np.float64)
    m = clip_from_world(width, height)
    clip = pts @ m[:, :3].T + m[:, 3]
    w = clip[..., 3:4]
    cols = (1.0 - clip[..., 0:1] / w) * 0.5 * width
    rows = (1.0 - clip[..., 1:2] / w) * 0.5 * height
    return np.concatenate([cols, rows], axis=-1), w[..., 0]


@functools.lru_cache(maxsize=8)
def unprojection(width: int, height: int) -> tuple[float, float, np.ndarray, np.ndarray]:
    """The constants :func:`generators.camera.unproject_to_plane` recomputes per call."""
    proj = projection_matrix(width / height)
    rot = view_matrix()[:3, :3]
    rot.setflags(write=False)
    eye = np.asarray(CAMERA_EYE, dtype=np.float64)
    eye.setflags(write=False)
    return float(proj[0, 0]), float(proj[1, 1]), rot, eye


def unproject(pixels: np.ndarray, width: int, height: int, plane_y: float) -> np.ndarray:
    """:func:`generators.camera.unproject_to_plane` with its matrices computed once per
    resolution (the same operations in the same order, so the same bits)."""
    px = np.asarray(pixels, dtype=np.float64)
    ndc_x = 1.0 - px[..., 0] / width * 2.0
    ndc_y = 1.0 - px[..., 1] / height * 2.0
    p00, p11, rot, eye = unprojection(width, height)
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
