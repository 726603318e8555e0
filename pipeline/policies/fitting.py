"""Fit the target's motion from noisy (time, XZ position) samples and extrapolate it.

Three model families, one per motion primitive (paper 3.1):

* ``line``: ``p(t) = p0 + u v t`` with a unit direction ``u`` (constant velocity:
  the linear tokens' small accelerations are not worth estimating from a short,
  noisy window and extrapolating for up to 1.5 s; :func:`fit_line` can fit them);
* ``arc``: ``p(t) = c + R (cos(w t + th), sin(w t + th))``, signed angular velocity ``w``;
* ``harmonic``: ``p(t) = c + d t + u (a sin(w t) + b cos(w t))``: oscillation along a
  unit axis ``u`` with a slow drift ``d``.

Every model is linear in its coefficients once its nonlinear parameters (the
direction, or the angular frequency) are fixed: directions come from principal
components, frequencies from a grid refined locally, both solved in batches with
normal equations. Models are compared with the Bayesian information criterion on
the residual (capped per sample, so outliers weigh alike), each parameter weighted
:data:`PARAM_PENALTY` times (perception errors are correlated from frame to frame, so
the samples say less than their number suggests), with a noise floor so that a
perfect fit of few points does not win by accident. One pass of outlier rejection
drops samples far off each family's first fit.

Every fitted model is a :class:`MotionFit`: coefficients ``C`` (2, k) over a basis
``phi(t)`` (k,), so position, velocity and acceleration are ``C phi``, ``C phi'``,
``C phi''``. Pure numpy, deterministic.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

KINDS = ("line", "arc", "harmonic")
#: Fewest samples each family needs.
MIN_SAMPLES = {"line": 3, "arc": 6, "harmonic": 8}
#: Residual floor (units) per coordinate: below this, fits are not told apart.
NOISE_FLOOR = 0.02
#: Weight of each parameter in the selection criterion (BIC's is 1).
PARAM_PENALTY = 2.0
#: Angular speeds (rad/s) the arc search covers, both turning directions.
ARC_OMEGAS = np.linspace(0.2, 4.0, 77)
#: Oscillation frequencies (rad/s) the harmonic search covers (0.1 - 1.0 Hz).
HARMONIC_OMEGAS = 2.0 * np.pi * np.linspace(0.1, 1.0, 91)
#: Ridge weight on the harmonic drift: drifts are slow, and a drift trades against a
#: low frequency when less than a period is seen.
DRIFT_RIDGE = 0.25
#: Samples further than this many median residuals (and than OUTLIER_MIN) are dropped.
OUTLIER_FACTOR = 4.0
OUTLIER_MIN = 0.15
_RIDGE = 1e-9


@dataclass(frozen=True)
class MotionFit:
    """A fitted motion. ``kind`` names the family (``line`` also when fitted with
    acceleration), ``coef`` (2, k) the coefficients over the family's basis,
    ``omega`` its angular frequency (0 for lines), ``rss`` the residual sum of squares
    over ``samples`` samples, ``params`` the model's free parameter count."""

    kind: str
    coef: np.ndarray
    omega: float
    rss: float
    samples: int
    params: int

    def _basis(self, t: np.ndarray, order: int) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        return basis(self.kind, self.omega, t, order)

    def position(self, t) -> np.ndarray:
        """(m, 2) XZ positions at times ``t`` (seconds)."""
        return self._basis(t, 0) @ self.coef.T

    def velocity(self, t) -> np.ndarray:
        return self._basis(t, 1) @ self.coef.T

    def acceleration(self, t) -> np.ndarray:
        return self._basis(t, 2) @ self.coef.T


def basis(kind: str, omega: float, t: np.ndarray, order: int = 0) -> np.ndarray:
    """(m, k) basis of a family at times ``t``, or its ``order``-th time derivative."""
    t = np.asarray(t, dtype=np.float64)
    one, zero = np.ones_like(t), np.zeros_like(t)
    if kind == "line":
        cols = [(one, t, t * t / 2.0), (zero, one, t), (zero, zero, one)][order]
        return np.stack(cols, axis=-1)
    s, c = np.sin(omega * t), np.cos(omega * t)
    trig = [(s, c), (omega * c, -omega * s), (-omega * omega * s, -omega * omega * c)][order]
    lead = [(one, t), (zero, one), (zero, zero)][order]
    return np.stack([lead[0], lead[1], trig[0], trig[1]], axis=-1)


def _solve(design: np.ndarray, target: np.ndarray, ridge: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Batched least squares via normal equations: design (..., n, k), target (..., n, d)
    -> coefficients (..., k, d) and residual sums (...,)."""
    gram = np.swapaxes(design, -1, -2) @ design
    k = design.shape[-1]
    reg = np.full(k, _RIDGE) if ridge is None else ridge + _RIDGE
    gram = gram + np.eye(k) * reg
    rhs = np.swapaxes(design, -1, -2) @ target
    coef = np.linalg.solve(gram, rhs)
    resid = target - design @ coef
    return coef, np.sum(resid * resid, axis=(-2, -1))


def fit_line(t: np.ndarray, xz: np.ndarray, accelerate: bool) -> MotionFit:
    """Straight-line fit: direction from principal components, then the path's
    coordinate along it as a quadratic (``accelerate``) or linear function of time."""
    mean = xz.mean(axis=0)
    centred = xz - mean
    # principal direction, oriented along the motion (later samples ahead)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    u = vt[0] if np.any(centred) else np.array([1.0, 0.0])
    ahead = np.dot(centred[-1] - centred[0], u)
    if ahead < 0:
        u = -u
    normal = np.array([-u[1], u[0]])
    along = centred @ u
    offset = float(np.mean(centred @ normal))
    design = basis("line", 0.0, t)
    if not accelerate:
        design = design[:, :2]
    coef, rss_along = _solve(design, along[:, None])
    path = np.zeros(3)
    path[: design.shape[1]] = coef[:, 0]
    cross = centred @ normal - offset
    rss = float(rss_along + np.sum(cross * cross))
    full = np.outer(u, path)
    full[:, 0] += mean + offset * normal
    return MotionFit("line", full, 0.0, rss, len(t), 5 if accelerate else 4)


def _refine(omegas: np.ndarray, costs: np.ndarray, evaluate, steps: int = 2) -> float:
    """Best grid frequency refined on finer local grids (deterministic)."""
    best = int(np.argmin(costs))
    omega = float(omegas[best])
    width = float(np.abs(omegas[min(best + 1, len(omegas) - 1)] - omegas[max(best - 1, 0)])) / 2.0 or 0.05
    for _ in range(steps):
        local = omega + np.linspace(-width, width, 11)
        local_costs = evaluate(local)
        omega = float(local[int(np.argmin(local_costs))])
        width /= 5.0
    return omega


def _arc_fit_at(t: np.ndarray, xz: np.ndarray, omegas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Circle-at-constant-angular-speed fits for each signed omega: coefficients (G, 2, 4)
    over the basis (1, t, sin, cos) and residual sums (G,)."""
    z = xz[:, 0] + 1j * xz[:, 1]
    rot = np.exp(1j * omegas[:, None] * t[None, :])  # (G, n)
    # z = c + B e^{i w t}: real unknowns (c_r, c_i, B_r, B_i)
    one = np.ones_like(rot.real)
    rows_x = np.stack([one, 0 * one, rot.real, -rot.imag], axis=-1)
    rows_z = np.stack([0 * one, one, rot.imag, rot.real], axis=-1)
    design = np.concatenate([rows_x, rows_z], axis=1)  # (G, 2n, 4)
    target = np.broadcast_to(np.concatenate([z.real, z.imag])[None, :, None], (len(omegas), 2 * len(t), 1))
    sol, rss = _solve(design, target)
    cr, ci, br, bi = (sol[:, k, 0] for k in range(4))
    coef = np.zeros((len(omegas), 2, 4))
    coef[:, 0, 0], coef[:, 1, 0] = cr, ci
    coef[:, 0, 2], coef[:, 0, 3] = -bi, br  # x = c_r + B_r cos - B_i sin
    coef[:, 1, 2], coef[:, 1, 3] = br, bi  # z = c_i + B_r sin + B_i cos
    return coef, rss


def fit_arc(t: np.ndarray, xz: np.ndarray) -> MotionFit:
    """Constant-speed circular fit: signed angular speed searched, centre and radius solved."""
    omegas = np.concatenate([-ARC_OMEGAS[::-1], ARC_OMEGAS])
    _, rss = _arc_fit_at(t, xz, omegas)
    omega = _refine(omegas, rss, lambda w: _arc_fit_at(t, xz, w)[1])
    coef, rss = _arc_fit_at(t, xz, np.array([omega]))
    return MotionFit("arc", coef[0], omega, float(rss[0]), len(t), 5)


def _harmonic_fit_at(t: np.ndarray, xz: np.ndarray, omegas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Oscillation-along-an-axis fits for each omega: coefficients (G, 2, 4) over the
    basis (1, t, sin, cos) and penalised residual sums (G,)."""
    g, n = len(omegas), len(t)
    s, c = np.sin(omegas[:, None] * t), np.cos(omegas[:, None] * t)
    one = np.ones((g, n))
    ridge = np.array([0.0, DRIFT_RIDGE, 0.0, 0.0])
    free = np.stack([one, np.broadcast_to(t, (g, n)), s, c], axis=-1)  # (G, n, 4)
    loose, _ = _solve(free, np.broadcast_to(xz, (g, n, 2)), ridge)
    # the axis: the dominant direction of the two oscillation vectors
    swing = np.swapaxes(loose[:, 2:, :], 1, 2)  # (G, 2 coords, 2 [sin, cos])
    u = np.linalg.svd(swing)[0][:, :, 0]  # (G, 2)
    zero = np.zeros((g, n))
    tt = np.broadcast_to(t, (g, n))
    rows_x = np.stack([one, zero, tt, zero, u[:, :1] * s, u[:, :1] * c], axis=-1)
    rows_z = np.stack([zero, one, zero, tt, u[:, 1:] * s, u[:, 1:] * c], axis=-1)
    design = np.concatenate([rows_x, rows_z], axis=1)  # (G, 2n, 6)
    target = np.broadcast_to(np.concatenate([xz[:, 0], xz[:, 1]])[None, :, None], (g, 2 * n, 1))
    ridge6 = np.array([0.0, 0.0, DRIFT_RIDGE, DRIFT_RIDGE, 0.0, 0.0])
    sol, rss = _solve(design, target, ridge6)
    sol = sol[..., 0]
    coef = np.zeros((g, 2, 4))
    coef[:, :, 0] = sol[:, 0:2]
    coef[:, :, 1] = sol[:, 2:4]
    coef[:, :, 2] = u * sol[:, 4:5]
    coef[:, :, 3] = u * sol[:, 5:6]
    drift = sol[:, 2] ** 2 + sol[:, 3] ** 2
    return coef, rss + DRIFT_RIDGE * drift


def fit_harmonic(t: np.ndarray, xz: np.ndarray) -> MotionFit:
    """Oscillation along an axis with drift: frequency searched, the rest solved."""
    _, cost = _harmonic_fit_at(t, xz, HARMONIC_OMEGAS)
    omega = _refine(HARMONIC_OMEGAS, cost, lambda w: _harmonic_fit_at(t, xz, w)[1])
    coef, _ = _harmonic_fit_at(t, xz, np.array([omega]))
    resid = xz - basis("harmonic", omega, t) @ coef[0].T
    return MotionFit("harmonic", coef[0], omega, float(np.sum(resid * resid)), len(t), 8)


def _fit_family(kind: str, t: np.ndarray, xz: np.ndarray) -> MotionFit | None:
    if len(t) < MIN_SAMPLES[kind]:
        return None
    if kind == "line":
        return fit_line(t, xz, accelerate=False)
    return fit_arc(t, xz) if kind == "arc" else fit_harmonic(t, xz)


def residuals(fit: MotionFit, t: np.ndarray, xz: np.ndarray) -> np.ndarray:
    """(n,) distances of the samples from the fitted positions."""
    return np.linalg.norm(fit.position(t) - xz, axis=1)


def fit_motion(
    times: Sequence[float] | np.ndarray, positions: Sequence[Sequence[float]] | np.ndarray, kinds: Sequence[str] = KINDS
) -> MotionFit | None:
    """The best model of ``kinds`` for samples at ``times`` (n,) with XZ ``positions``
    (n, 2), by :func:`selection_score` after one pass of outlier rejection; None with too few samples."""
    t = np.asarray(times, dtype=np.float64)
    xz = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    if len(t) != len(xz):
        raise ValueError(f"need as many times as positions, got {len(t)} and {len(xz)}")
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        raise ValueError(f"unknown motion model(s) {unknown}; expected some of {list(KINDS)}")
    best: MotionFit | None = None
    best_score = np.inf
    for kind in kinds:
        fit = _fit_family(kind, t, xz)
        if fit is None:
            continue
        r = residuals(fit, t, xz)
        keep = r <= max(OUTLIER_FACTOR * float(np.median(r)), OUTLIER_MIN)
        if not keep.all() and keep.sum() >= MIN_SAMPLES[kind]:
            refit = _fit_family(kind, t[keep], xz[keep])
            if refit is not None:
                fit = refit
        score = selection_score(fit, t, xz)
        if score < best_score:
            best, best_score = fit, score
    return best


def selection_score(fit: MotionFit, t: np.ndarray, xz: np.ndarray) -> float:
    """BIC-like score over all samples (lower is better): each residual capped at
    :data:`OUTLIER_MIN`, so that fits that dropped different outliers compare on the
    same samples, and each parameter weighted :data:`PARAM_PENALTY` times."""
    r = np.minimum(residuals(fit, t, xz), OUTLIER_MIN)
    n = 2 * len(t)
    rss = max(float(np.sum(r * r)), n * NOISE_FLOOR**2)
    return n * np.log(rss / n) + PARAM_PENALTY * fit.params * np.log(n)
