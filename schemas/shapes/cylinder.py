"""A cylinder, ``dims`` (radius, length): its axis along local +Y upright, +X lying; a
lying one rolls on an axle (its markings two stripes along it), an upright one has a lid ring."""

from __future__ import annotations

import math

import numpy as np

from schemas.shapes.base import Z_TO_X, Z_TO_Y, ObjectShape, Solid, VisualPart, register, rim


@register("cylinder")
class Cylinder(ObjectShape):
    dims = ("radius", "length")

    def half_height(self, dims, lying):
        return dims[0] if lying else dims[1] / 2.0

    def roll_mode(self, lying):
        return "axle" if lying else None

    def signed_distance(self, points, dims, axis):
        p = np.asarray(points, dtype=np.float64)
        u, v = [k for k in range(3) if k != axis]
        radial = np.hypot(p[..., u], p[..., v]) - dims[0]
        axial = np.abs(p[..., axis]) - dims[1] / 2.0
        outside = np.hypot(np.maximum(radial, 0.0), np.maximum(axial, 0.0))
        return outside + np.minimum(np.maximum(radial, axial), 0.0)

    def hull_points(self, dims, lying):
        radius, length = dims
        axis = np.eye(3)[self.axis(lying)]
        return np.concatenate([rim(s * length / 2.0 * axis, axis, radius) for s in (-1.0, 1.0)])

    def reach(self, dims, lying, hypot=math.hypot):
        return float(hypot(dims[0], dims[1] / 2.0)) if lying else float(dims[0])

    def silhouette_points(self, dims, lying, heading):
        r, length = dims
        ring = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
        if lying:
            axis = np.array([np.cos(heading), 0.0, np.sin(heading)])
            side = np.cross(axis, [0.0, 1.0, 0.0])
            band = np.outer(r * np.cos(ring), side) + np.outer(r * np.sin(ring), [0.0, 1.0, 0.0])
            return np.vstack([band + axis * length / 2, band - axis * length / 2])
        band = np.stack([r * np.cos(ring), np.zeros(len(ring)), r * np.sin(ring)], axis=-1)
        return np.vstack([band + [0.0, length / 2, 0.0], band - [0.0, length / 2, 0.0]])

    def headings(self, lying):
        return tuple(np.linspace(0.0, np.pi, 6, endpoint=False)) if lying else (0.0,)

    def visual_parts(self, dims, lying, rgba, mark):
        r, length = dims
        if lying:
            stripe = (0.49 * length, 0.04 * r, 0.22 * r)
            return [
                VisualPart("cylinder", (r, length), rgba, orientation=Z_TO_X),
                VisualPart("box", stripe, mark, position=(0.0, 0.98 * r, 0.0)),
                VisualPart("box", stripe, mark, position=(0.0, -0.98 * r, 0.0)),
            ]
        return [
            VisualPart("cylinder", (r, length), rgba, orientation=Z_TO_Y),
            VisualPart("cylinder", (0.82 * r, 0.02 * r), mark, (0.0, length / 2, 0.0), Z_TO_Y),
        ]

    def solid(self, dims, lying):
        return Solid("cylinder", (dims[0], dims[1] / 2.0), (1, 2, 0) if lying else (2, 0, 1))
