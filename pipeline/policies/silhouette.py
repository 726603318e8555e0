"""Object silhouettes: a category's projected shape at a size, position and heading, grown
by JPEG's halo, and its match against a blob by shifting it (:mod:`pipeline.policies.perception`,
step 4)."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from pipeline.policies.camera_model import project
from pipeline.policies.hand_shape import convex_hull, hull_depth, pixel_window
from schemas.objects import ObjectCategory

#: Silhouette templates are grown by this many pixels to match JPEG's halo.
HALO_PX = 1.0


@functools.lru_cache(maxsize=256)
def surface_points(category: ObjectCategory, size: float, heading: float) -> np.ndarray:
    """Points (m, 3) whose convex hull is the object's body at ``size``, centre at the origin
    (read-only: cached, as a window's frames share size and heading).

    ``heading`` turns a lying cylinder's axis in the XZ plane; other shapes ignore it
    (non-rolling objects keep their orientation; a sphere looks the same any way).
    """
    points = body_points(category, size, heading)
    points.setflags(write=False)
    return points


def body_points(category: ObjectCategory, size: float, heading: float) -> np.ndarray:
    return category.geometry.silhouette_points(category.scaled_dims(size), category.lying, heading)


def headings(category: ObjectCategory) -> tuple[float, ...]:
    """The orientations a template search tries: six headings for lying cylinders."""
    return category.geometry.headings(category.lying)


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
    px, _ = project(centre + surface_points(category, size, heading), width, height)
    hull = convex_hull(px)
    win = pixel_window(px.min(axis=0) - HALO_PX, px.max(axis=0) + HALO_PX, width, height)
    if win is None:
        return None
    (rows, cols), xs, ys = win
    depth = hull_depth(xs, ys, hull)
    mask = depth >= -HALO_PX
    area = int(np.count_nonzero(depth >= 0.0))
    if area == 0:
        return None
    return Template(mask, (rows.start, cols.start), project(centre, width, height)[0], area)


def crop(image: np.ndarray, r0: int, c0: int, h: int, w: int) -> np.ndarray:
    """``image[r0:r0+h, c0:c0+w]`` as int64, zero outside the image."""
    out = np.zeros((h, w), dtype=np.int64)
    rr0, cc0 = max(r0, 0), max(c0, 0)
    rr1, cc1 = min(r0 + h, image.shape[0]), min(c0 + w, image.shape[1])
    if rr0 < rr1 and cc0 < cc1:
        out[rr0 - r0 : rr1 - r0, cc0 - c0 : cc1 - c0] = image[rr0:rr1, cc0:cc1]
    return out


def correlate(images: np.ndarray, tpl: Template, reach: int, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Overlap counts (k, 2 reach + 1, 2 reach + 1) of each image (k, H, W) with the
    template shifted by (row, col) offsets in [-reach, reach]; exact integers (FFT,
    rounded). The images' top-left pixel is ``origin`` (row, col) of the frame, and
    they are taken as zero outside."""
    h, w = tpl.mask.shape
    r0, c0 = tpl.origin[0] - origin[0], tpl.origin[1] - origin[1]
    crops = np.stack([crop(image, r0 - reach, c0 - reach, h + 2 * reach, w + 2 * reach) for image in images])
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
    on_background, on_blob = correlate(np.stack([background, blob]), tpl, reach, origin)
    score = on_background + int(blob.sum()) - on_blob
    best = int(score.min())
    rows, cols = np.nonzero(score == best)
    return np.array([cols.mean() - reach, rows.mean() - reach]), best
