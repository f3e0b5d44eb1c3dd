"""The wall's local deviation from the circle, from scattered points: a robust local quadratic regression
(LOESS) of the deviation d over the wall (h along, s = R phi around) at the nodes of a grid, with the
bandwidth chosen per node by the intersection of confidence intervals (ICI).

Why this shape: a dent's depth is the extreme of a smooth surface sampled by sparse, noisy points. Cell
medians read it shallow (a cell averages over the dent's flank, and a cell holds only a few points), and a
global fit of a few harmonics spreads it round the circle. A local quadratic follows a smooth extreme
without flattening it (its bias is of fourth order in the bandwidth), and ICI takes the widest
neighbourhood whose estimate still agrees with every narrower one: wide (quiet) where the wall is
smooth, narrow where it curves, so neither the dent nor the noise floor of a round wall decides alone.

Steps: (1) each point's leave-one-out local quadratic predicts it; points farther off than
`outlier_mads` robust SDs of those residuals (bad triangulations) are dropped, while the points of a dent,
which their neighbours' quadratic follows, are kept; (2) at each node, the local quadratic fits of the
`neighbours` nearest points (tricube weights) give estimates with standard deviations sigma * |l| (l the
fit's equivalent kernel, sigma the points' noise from step 1); ICI keeps the estimate of the largest
neighbourhood whose interval +- gamma SD meets all smaller ones'. A node has no value where its nearest
point lies farther than `reach_m` or its neighbours lie lopsided (their weighted centroid more than
MAX_LEAN bandwidths off): at the edge of a gap the quadratic would extrapolate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

LOO_NEIGHBOURS = 30
ROWS_AT_ONCE = 4096  # points or nodes whose neighbourhoods are fitted together
MAX_LEAN = 0.3  # the neighbours' weighted centroid may lie this far (in bandwidths) from the node


@dataclass(frozen=True)
class WallField:
    """Deviation estimates at grid nodes: h (n,), phi (n,) and value (n,) (NaN: no support)."""

    h: np.ndarray
    phi: np.ndarray
    value: np.ndarray
    sigma: float  # the points' noise (robust SD of the leave-one-out residuals)
    points: int  # points kept after outliers


def _design(dh: np.ndarray, ds: np.ndarray) -> np.ndarray:
    return np.stack([np.ones_like(dh), dh, ds, dh * dh, dh * ds, ds * ds], axis=-1)


def _tricube(dist: np.ndarray, k: int) -> np.ndarray:
    bw = dist[:, k - 1:k] * 1.0001 + 1e-12
    u = np.minimum(dist[:, :k] / bw, 1.0)
    return (1 - u ** 3) ** 3


def _equivalent_kernel(X: np.ndarray, w: np.ndarray) -> np.ndarray:
    """l (n, k): the weights that give the fitted value at the node (the constant term) from the points."""
    A = np.einsum("nk,nki,nkj->nij", w, X, X) + np.eye(X.shape[-1]) * 1e-14
    e0 = np.zeros((len(A), X.shape[-1], 1))
    e0[:, 0] = 1.0
    ok = np.linalg.cond(A) < 1e12
    z = np.full((len(A), X.shape[-1]), np.nan)
    if ok.any():
        z[ok] = np.linalg.solve(A[ok], e0[ok])[..., 0]
    return w * np.einsum("nki,ni->nk", X, z)


class _Wall:
    """Points on the unrolled wall (h, s = R phi), periodic around."""

    def __init__(self, h: np.ndarray, phi: np.ndarray, radius: float):
        self.C = 2 * np.pi * radius
        self.h0 = float(h.min())
        self.h = h - self.h0
        self.s = np.mod(phi, 2 * np.pi) * radius
        self.tree = cKDTree(np.column_stack([self.h, np.minimum(self.s, np.nextafter(self.C, 0))]),
                            boxsize=[max(1e3, 4 * float(self.h.max()) + 1.0), self.C])

    def neighbours(self, h: np.ndarray, s: np.ndarray, k: int):
        dist, idx = self.tree.query(np.column_stack([h, np.mod(s, self.C)]), k=k)
        dh = self.h[idx] - h[:, None]
        ds = np.mod(self.s[idx] - s[:, None] + self.C / 2, self.C) - self.C / 2
        return dist, idx, _design(dh, ds)


def _loo_residuals(wall: _Wall, d: np.ndarray) -> np.ndarray:
    """Each point's deviation less its leave-one-out local quadratic prediction."""
    res = np.empty(len(d))
    for rows in _chunks(len(d)):
        dist, idx, X = wall.neighbours(wall.h[rows], wall.s[rows], LOO_NEIGHBOURS + 1)
        l = _equivalent_kernel(X[:, 1:], _tricube(dist[:, 1:], LOO_NEIGHBOURS))  # without the point itself
        res[rows] = d[rows] - np.einsum("nk,nk->n", l, d[idx[:, 1:]])
    return res


def _node_values(wall: _Wall, d: np.ndarray, H: np.ndarray, S: np.ndarray, neighbours: tuple[int, ...],
                 gamma: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """ICI estimates at nodes (H, S) and each node's nearest point's distance."""
    dist, idx, X = wall.neighbours(H, S, max(neighbours))
    value = lo = hi = None
    alive = np.ones(len(H), bool)
    for k in sorted(neighbours):
        w = _tricube(dist, k)
        l = _equivalent_kernel(X[:, :k], w)
        v = np.einsum("nk,nk->n", l, d[idx[:, :k]])
        # a node at the edge of a gap has its neighbours on one side: the quadratic would extrapolate
        lean = np.hypot(*(np.einsum("nk,nk->n", w, X[:, :k, j]) for j in (1, 2))) / (w.sum(axis=1) + 1e-12)
        v = np.where(lean <= MAX_LEAN * dist[:, k - 1], v, np.nan)
        half = gamma * sigma * np.sqrt(np.einsum("nk,nk->n", l, l))
        if value is None:
            value, lo, hi = v, v - half, v + half
            alive = np.isfinite(v)
            continue
        lo, hi = np.maximum(lo, v - half), np.minimum(hi, v + half)
        alive &= (lo <= hi) & np.isfinite(v)
        value = np.where(alive, v, value)
    return value, dist[:, 0]


def _chunks(n: int):
    """Row slices of at most ROWS_AT_ONCE: every row is independent, and a long piece's nodes times 80
    neighbours times the quadratic's 6 terms took gigabytes at once."""
    return (slice(a, a + ROWS_AT_ONCE) for a in range(0, n, ROWS_AT_ONCE))


def wall_field(h: np.ndarray, phi: np.ndarray, d: np.ndarray, radius: float, h_nodes: np.ndarray, *,
               grid_m: float, neighbours: tuple[int, ...], gamma: float, outlier_mads: float,
               reach_m: float) -> WallField | None:
    """The deviation field at h_nodes x a ring of nodes every grid_m around (None: too few points)."""
    h, phi, d = (np.asarray(a, float) for a in (h, phi, d))
    if len(h) < 2 * max(neighbours):
        return None
    res = _loo_residuals(_Wall(h, phi, radius), d)
    res = np.where(np.isfinite(res), res, np.inf)
    sigma = 1.4826 * float(np.median(np.abs(res))) + 1e-9
    keep = np.abs(res) <= outlier_mads * sigma
    if keep.sum() < 2 * max(neighbours):
        return None
    wall = _Wall(h[keep], phi[keep], radius)
    d = d[keep]
    n_around = max(8, int(round(wall.C / grid_m)))
    H, S = np.meshgrid(np.asarray(h_nodes, float) - wall.h0, np.arange(n_around) * wall.C / n_around, indexing="ij")
    H, S = H.ravel(), S.ravel()
    value, nearest = np.empty(len(H)), np.empty(len(H))
    for rows in _chunks(len(H)):
        value[rows], nearest[rows] = _node_values(wall, d, H[rows], S[rows], neighbours, gamma, sigma)
    value = np.where(nearest <= reach_m, value, np.nan)
    return WallField(H + wall.h0, S / radius, value, sigma, int(keep.sum()))


__all__ = ["WallField", "wall_field"]
