"""A box, ``dims`` half extents (hx, hy, hz) along local X, Y, Z: never rolls; its marking
is a band on its top."""

from __future__ import annotations

import math

import numpy as np

from schemas.shapes.base import BOX_SIGNS, ObjectShape, Solid, VisualPart, register


@register("box")
class Box(ObjectShape):
    dims = ("hx", "hy", "hz")

    def nominal_size(self, dims):
        return 2.0 * max(dims[0], dims[2])

    def half_height(self, dims, lying):
        return dims[1]

    def roll_mode(self, lying):
        return None

    def signed_distance(self, points, dims, axis):
        q = np.abs(np.asarray(points, dtype=np.float64)) - np.asarray(dims)
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        return outside + np.minimum(q.max(axis=-1), 0.0)

    def hull_points(self, dims, lying):
        return BOX_SIGNS * np.asarray(dims)

    def reach(self, dims, lying, hypot=math.hypot):
        return float(hypot(dims[0], dims[2]))

    def silhouette_points(self, dims, lying, heading):
        return BOX_SIGNS * np.asarray(dims)

    def visual_parts(self, dims, lying, rgba, mark):
        hx, hy, hz = dims
        return [
            VisualPart("box", (hx, hy, hz), rgba),
            VisualPart("box", (0.6 * hx, 0.02 * hy, 0.5 * hz), mark, (0.0, hy, 0.0)),
        ]

    def solid(self, dims, lying):
        return Solid("box", tuple(dims))
