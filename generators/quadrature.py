"""Fixed-order quadrature shared by the path integrals (arc length, rolling, clothoids).

Sums are accumulated term by term in a fixed order, so a row's result never depends on
how many rows are evaluated together (a BLAS product could): the determinism rule.
"""

from __future__ import annotations

import math

import numpy as np

#: 3-point Gauss-Legendre nodes on [0, 1] and their weights (6th order).
GL3_NODES = np.array([0.5 - math.sqrt(0.15), 0.5, 0.5 + math.sqrt(0.15)])
GL3_WEIGHTS = np.array([5.0, 8.0, 5.0]) / 18.0


def weighted_sum(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Row-wise weighted sums, accumulated term by term in a fixed order: unlike a BLAS
    product, a row's result does not depend on how many rows there are."""
    out = values[:, 0] * weights[0]
    for j in range(1, weights.shape[0]):
        out = out + values[:, j] * weights[j]
    return out


def node_times(a: np.ndarray, h: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Times ``a + h * x`` for each quadrature node ``x``, shape ``(len(a), len(nodes))``."""
    return a[:, None] + h[:, None] * nodes[None, :]
