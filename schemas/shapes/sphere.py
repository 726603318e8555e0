"""A sphere, ``dims`` (radius,): rolls like a ball; its markings are two crossing seams."""

from __future__ import annotations

import math

import numpy as np

from schemas.shapes.base import UNIT_SPHERE, Z_TO_X, ObjectShape, Solid, VisualPart, register


@register("sphere")
class Sphere(ObjectShape):
    dims = ("radius",)

    def half_height(self, dims, lying):
        return dims[0]

    def roll_mode(self, lying):
        return "ball"

    def signed_distance(self, points, dims, axis):
        return np.linalg.norm(np.asarray(points, dtype=np.float64), axis=-1) - dims[0]

    def hull_points(self, dims, lying):
        return dims[0] * UNIT_SPHERE

    def reach(self, dims, lying, hypot=math.hypot):
        return float(dims[0])

    def silhouette_points(self, dims, lying, heading):
        ring = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
        u, v = np.meshgrid(np.linspace(0.0, np.pi, 9), ring)
        return dims[0] * np.stack([np.sin(u) * np.cos(v), np.cos(u), np.sin(u) * np.sin(v)], axis=-1).reshape(-1, 3)

    def visual_parts(self, dims, lying, rgba, mark):
        r = dims[0]
        seam = (1.02 * r, 0.16 * r)
        return [
            VisualPart("sphere", (r,), rgba),
            VisualPart("cylinder", seam, mark, orientation=Z_TO_X),
            VisualPart("cylinder", seam, mark),
        ]

    def solid(self, dims, lying):
        return Solid("sphere", (dims[0],))
