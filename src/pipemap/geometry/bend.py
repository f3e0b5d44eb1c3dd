"""A pipe axis that bends a little: offsets of the axis from a straight line, at knots along it.

Pipe runs are laid from pieces that sag between their supports and meet at slightly kinked
joints: a few millimetres over a few metres. A straight cylinder fitted over such a run leaves
its wall that far off, and in a window solve the cylinder term straightens the trajectory to
match. The bent axis is the straight axis plus an offset o(z) across it, linear between knots
z_0 < ... < z_{K-1} evenly spaced along the axis and constant beyond the end knots.

Offsets are held near the straight line by a prior with two terms, both as residuals whose
square is a cost in the units of a squared reprojection error (pixels^2):
- each knot offset over `offset_sigma_m`. At the least this fixes the gauge (a linear trend of
  the offsets is the same as a tilted or shifted straight axis). In a window solve it also
  does what the straight cylinder did: an axis free to curve lets the heading drift with it,
  the very drift the cylinder is there to stop, so there it is held to millimetres;
- each kink, the change of slope at an inner knot (o_{k-1} - 2 o_k + o_{k+1}) / spacing, over
  `kink_sigma_rad`: how sharply the pipe is expected to bend.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Weak: only decides how a linear trend is split between the straight axis and the offsets.
OFFSET_SIGMA_M = 0.01


@dataclass(frozen=True)
class AxisKnots:
    """Evenly spaced knots z (K,) along an axis (K >= 2)."""

    z: np.ndarray

    def __post_init__(self):
        z = np.asarray(self.z, float).reshape(-1)
        if len(z) < 2 or not np.all(np.isfinite(z)) or not np.all(np.diff(z) > 0):
            raise ValueError("knots must be at least two increasing finite numbers")
        object.__setattr__(self, "z", z)

    @classmethod
    def spanning(cls, z_min: float, z_max: float, spacing: float) -> "AxisKnots":
        """Knots from z_min to z_max at most `spacing` apart."""
        if not (spacing > 0 and math.isfinite(spacing)):
            raise ValueError(f"knot spacing must be positive, got {spacing!r}")
        span = max(float(z_max) - float(z_min), 1e-9)
        return cls(np.linspace(float(z_min), float(z_min) + span, max(2, math.ceil(span / spacing) + 1)))

    def __len__(self) -> int:
        return len(self.z)

    @property
    def spacing(self) -> float:
        return float(self.z[1] - self.z[0])

    def segment(self, z) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each z: the segment index i (offset = (1 - f) o_i + f o_{i+1}), the fraction f and
        whether z lies between the end knots (beyond them the offset is constant, its slope 0)."""
        z = np.asarray(z, float)
        i = np.clip(np.searchsorted(self.z, z, side="right") - 1, 0, len(self.z) - 2)
        f = (z - self.z[i]) / (self.z[i + 1] - self.z[i])
        inside = (f >= 0.0) & (f <= 1.0)
        return i, np.clip(f, 0.0, 1.0), inside

    def at(self, offsets: np.ndarray, z) -> np.ndarray:
        """Offsets (K, D) interpolated at z (...,): (..., D)."""
        return self._offset_and_slope(offsets, *self.segment(z))[0]

    def slope(self, offsets: np.ndarray, z) -> np.ndarray:
        """d offset / dz at z (..., D); 0 beyond the end knots."""
        return self._offset_and_slope(offsets, *self.segment(z))[1]

    def _offset_and_slope(self, offsets, i, f, inside) -> tuple[np.ndarray, np.ndarray]:
        o = np.asarray(offsets, float)
        value = (1.0 - f)[..., None] * o[i] + f[..., None] * o[i + 1]
        slope = np.where(inside[..., None], (o[i + 1] - o[i]) / (self.z[i + 1] - self.z[i])[..., None], 0.0)
        return value, slope

    def prior(self, dims: int, kink_sigma_rad: float, offset_sigma_m=OFFSET_SIGMA_M) -> np.ndarray:
        """The prior's constant Jacobian P: residuals P @ offsets.ravel() for offsets (K, dims);
        offset_sigma_m is one sigma or one per dimension."""
        K = len(self.z)
        sigma = np.broadcast_to(np.asarray(offset_sigma_m, float), (dims,))
        rows = [np.kron(np.eye(K), np.diag(1.0 / sigma))]
        if K > 2:
            D = np.zeros((K - 2, K))
            k = np.arange(K - 2)
            D[k, k], D[k, k + 1], D[k, k + 2] = 1.0, -2.0, 1.0
            rows.append(np.kron(D / (self.spacing * kink_sigma_rad), np.eye(dims)))
        return np.vstack(rows)


def bent_distance(xy: np.ndarray, z: np.ndarray, knots: AxisKnots | None, offsets: np.ndarray | None,
                  radius: float):
    """Signed wall distance of points given in an axis frame (axis = z) around the bent axis, and
    its derivatives: d (M,), n (M, 3) = d d / d (x, y, z), and per point the two knots i, i+1 and
    weights (1 - f, f) through which d d / d o = -weight * n_xy."""
    xy = np.asarray(xy, float)
    if knots is None:
        v = xy
        i = np.zeros(len(xy), np.int64)
        f = np.zeros(len(xy))
    else:
        i, f, inside = knots.segment(z)
        o, slope = knots._offset_and_slope(offsets, i, f, inside)
        v = xy - o
    rho = np.hypot(v[:, 0], v[:, 1])
    n = np.empty((len(xy), 3))
    np.divide(v, np.where(rho > 0, rho, 1.0)[:, None], out=n[:, :2])
    n[:, 2] = 0.0 if knots is None else -np.einsum("mi,mi->m", n[:, :2], slope)
    return rho - radius, n, i, f


def fit_bend(axial: np.ndarray, across: np.ndarray, radius: float, spacing: float, kink_sigma_rad: float,
             huber: float, sigma_m: float, offset_sigma_m: float = OFFSET_SIGMA_M,
             iterations: int = 5) -> tuple[AxisKnots, np.ndarray]:
    """Knots and offsets (K, 2) of a bent axis fitted to wall points given by their coordinate
    along a straight axis (M,) and their position across it (M, 2), the radius known. Point
    distances count as residuals over `sigma_m` (Huber at `huber` metres), so the prior weighs
    against them as in a window solve. Iteratively re-weighted linear least squares: the offsets
    are millimetres, far below the radius, so d is linear in them to well under a micrometre."""
    knots = AxisKnots.spanning(float(np.min(axial)), float(np.max(axial)), spacing)
    K = len(knots)
    P = knots.prior(2, kink_sigma_rad, offset_sigma_m)
    o = np.zeros((K, 2))
    i, f, _ = knots.segment(axial)
    for _ in range(iterations):
        d, n, _, _ = bent_distance(across, axial, knots, o, radius)
        w = np.where(np.abs(d) <= huber, 1.0, huber / np.maximum(np.abs(d), 1e-300)) / sigma_m**2
        H, g = _knot_normal_equations(i, f, n[:, :2], w, d, K)
        step = np.linalg.solve(H + P.T @ P, -(g + P.T @ (P @ o.ravel())))
        o = o + step.reshape(K, 2)
        if np.max(np.abs(step)) < 1e-7:
            break
    return knots, o


def _knot_normal_equations(i, f, n_xy, w, d, K: int) -> tuple[np.ndarray, np.ndarray]:
    """J^T W J (2K, 2K) and J^T W d (2K,) of the distances d (M,), J = d d / d offsets, summed point by
    point: a point's row touches only its two knots, so the (M, 2K) Jacobian, gigabytes over a long
    section, is never formed."""
    a = (1.0 - f)[:, None] * n_xy  # -d d / d o_i
    b = f[:, None] * n_xy  # -d d / d o_{i+1}
    H = np.zeros((K, 2, K, 2))
    for lo, hi, u, v in ((0, 0, a, a), (0, 1, a, b), (1, 1, b, b)):
        block = np.stack([np.bincount(i, w * u[:, r] * v[:, c], minlength=K - 1) for r in (0, 1) for c in (0, 1)],
                         axis=-1).reshape(K - 1, 2, 2)
        rows, cols = np.arange(K - 1) + lo, np.arange(K - 1) + hi
        H[rows, :, cols, :] += block
        if lo != hi:
            H[cols, :, rows, :] += block.transpose(0, 2, 1)
    g = np.zeros((K, 2))
    wd = w * d
    for lo, u in ((0, a), (1, b)):
        g[lo:K - 1 + lo] -= np.column_stack([np.bincount(i, wd * u[:, c], minlength=K - 1) for c in (0, 1)])
    return H.reshape(2 * K, 2 * K), g.ravel()


__all__ = ["AxisKnots", "bent_distance", "fit_bend", "OFFSET_SIGMA_M"]
