"""The local second-order shape of the image motion between two keyframes, from their matches.

A patch matcher with an affine warp (anchor.py) finds the centre of its window only as well as the
true image motion is affine across that window. Between two views of the pipe wall it is not: the
fisheye and the oblique view of the wall bend it, and an affine fit over a window of half-width w
moves the centre by about H w^2 / 6, where H is the motion's second derivative. On the fisheye at
640x480 that was +0.05 px outwards near the optical axis and -0.04 to -0.1 px inwards towards the
rim after a few keyframes, always the same way, so it shortened every section by 0.06-0.07 %.

Here the motion around each point is fitted, from the matches of its neighbours, as a quadratic
function of position, y = c + J d + 1/2 d^T H d (d = x - point). Nothing about the scene or camera is
assumed: the neighbours' matches themselves show how the image bends.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from pipemap.solvers import mad_sigma


def _design(d: np.ndarray) -> np.ndarray:
    """Quadratic monomials (1, u, v, u^2/2, uv, v^2/2) of offsets d (..., 2)."""
    u, v = d[..., 0], d[..., 1]
    return np.stack([np.ones_like(u), u, v, 0.5 * u * u, u * v, 0.5 * v * v], axis=-1)


def _well_conditioned(A: np.ndarray) -> np.ndarray:
    """(M,) whether each normal matrix (M, c, c) has its least eigenvalue above 1e-6 of its largest. A batched
    Cholesky of A less that margin (the largest eigenvalue bounded by the trace) decides every matrix at once
    when all pass, ten times faster than their eigenvalues; otherwise the eigenvalues decide."""
    trace = np.trace(A, axis1=1, axis2=2)
    try:
        np.linalg.cholesky(A - (1e-6 * trace)[:, None, None] * np.eye(A.shape[1]))
        return np.ones(len(A), bool)
    except np.linalg.LinAlgError:
        eig = np.linalg.eigvalsh(A)
        return eig[:, 0] > 1e-6 * np.maximum(eig[:, -1], 1e-30)


def _fit(X: np.ndarray, Y: np.ndarray, w: np.ndarray, max_residual_px: float):
    """Weighted least-squares fits Y ~ X coef per point (X (M, k, cols), Y (M, k, 2), w (M, k)):
    (well conditioned (M,), coef (M, cols, 2), the weights of the next pass (M, k))."""
    cols = X.shape[2]
    Xc = np.ascontiguousarray(X)
    XtW = np.swapaxes(Xc * w[..., None], 1, 2)
    A = XtW @ Xc
    b = XtW @ Y
    good = _well_conditioned(A)
    A[~good] = np.eye(cols)
    coef = np.linalg.solve(A, b)  # (M, cols, 2)
    r = Xc @ coef - Y
    res = np.hypot(r[..., 0], r[..., 1])
    sigma = mad_sigma(res, centre=0.0, axis=1, keepdims=True)
    return good, coef, (res <= np.maximum(3.0 * sigma, max_residual_px)).astype(float)


def local_quadratic_motion(src: np.ndarray, dst: np.ndarray, at: np.ndarray, neighbours: int = 32,
                           max_residual_px: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit dst = c + J d + 1/2 d^T H_k d around each point of `at` (M, 2) to the `neighbours` matches
    src -> dst (N, 2) nearest to it. Returns J (M, 2, 2), H (M, 2, 2, 2) with H[m, k] the symmetric
    second derivative of component k, and ok (M,): False (J = I, H = 0) where too few matches lie
    around the point, or spread too thinly to fix a quadratic. Matches off the fit by more than
    `max_residual_px` (or 3 MAD of an affine fit, then of the quadratic one) are dropped and the
    fit repeated."""
    src = np.asarray(src, np.float64).reshape(-1, 2)
    dst = np.asarray(dst, np.float64).reshape(-1, 2)
    at = np.asarray(at, np.float64).reshape(-1, 2)
    m = len(at)
    J = np.tile(np.eye(2), (m, 1, 1))
    H = np.zeros((m, 2, 2, 2))
    ok = np.zeros(m, bool)
    k = min(int(neighbours), len(src))
    if m == 0 or k < 12:
        return J, H, ok
    dist, idx = cKDTree(src).query(at, k=k)
    scale = np.maximum(dist[:, -1], 1.0)[:, None, None]  # offsets in units of the neighbourhood radius
    d = (src[idx] - at[:, None, :]) / scale
    X = _design(d)  # (M, k, 6)
    Y = dst[idx] - at[:, None, :]  # (M, k, 2)
    w = np.ones(idx.shape)
    # Affine fits first (fewer unknowns, less pulled by a wrong match), then the quadratic one. A fit
    # repeated with the same weights gives the same result, so a repeat refits only the points whose
    # weights changed (each point's fit is its own).
    rows, last = np.arange(m), 0
    for cols in (3, 3, 6, 6, 6):
        if cols != last:
            rows, last = np.arange(m), cols
            good, coef = np.zeros(m, bool), np.zeros((m, cols, 2))
        at_rows = slice(None) if len(rows) == m else rows  # a slice takes no copy of X
        good[at_rows], coef[at_rows], w_rows = _fit(X[at_rows, :, :cols], Y[at_rows], w[at_rows], max_residual_px)
        changed = np.any(w_rows != w[at_rows], axis=1)
        w[at_rows] = w_rows
        rows = rows[changed]
    # A point at the edge of its neighbourhood (the rim of the view, the dark far end of the pipe)
    # would take its second derivatives from an extrapolation.
    centred = np.linalg.norm((w[:, None, :] @ d)[:, 0] / np.maximum(w.sum(axis=1), 1)[:, None], axis=1) < 0.4
    ok = good & (w.sum(axis=1) >= 12) & centred
    s = scale[:, 0, 0]
    J[ok] = np.transpose(coef[ok, 1:3, :], (0, 2, 1)) / s[ok, None, None]
    c = coef[ok, 3:6, :] / (s[ok] ** 2)[:, None, None]  # (huu, huv, hvv) per component
    H[ok, :, 0, 0], H[ok, :, 0, 1], H[ok, :, 1, 1] = c[:, 0].copy(), c[:, 1].copy(), c[:, 2].copy()
    H[ok, :, 1, 0] = H[ok, :, 0, 1]
    return J, H, ok


__all__ = ["local_quadratic_motion"]
