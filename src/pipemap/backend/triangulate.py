"""Triangulation of scene points from bearing vectors (fisheye paper III-C).

Works on unit bearings, so rays beyond 90 deg from the optical axis are handled like any other
(the fisheye sees up to 95 deg and the pipe wall is mostly seen there).

`triangulate_rays` is the multi-view midpoint: the point X minimising the sum of squared
perpendicular distances to the rays c_k + s d_k, refined by a few Gauss-Newton steps on the
angular (tangent-plane) error of the bearings -- the error on the view sphere, which is what the
"optimal" two-view triangulation minimises; on exact bearings both are exact. Each point has
any number (>= 2) of observations; everything is vectorised over points.

Checks: cheirality (the point lies in front of every ray, s_k > 0) and parallax (the widest
angle between two of its rays, seen from the point, is at least `min_parallax_deg`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Triangulation:
    points: np.ndarray  # (M, 3) world
    valid: np.ndarray  # (M,) bool: in front of every ray, enough parallax, finite
    parallax_deg: np.ndarray  # (M,) widest angle between the point's rays
    in_front: np.ndarray  # (M,) bool: cheirality alone
    max_error_deg: np.ndarray  # (M,) largest angle between an observed bearing and the ray to the point


def _sum_by(index: np.ndarray, values: np.ndarray, count: int) -> np.ndarray:
    """Sum rows of `values` (K, ...) into `count` bins by `index` (K,)."""
    out = np.zeros((count,) + values.shape[1:])
    np.add.at(out, index, values)
    return out


def triangulate_rays(centres: np.ndarray, directions: np.ndarray, point: np.ndarray, count: int | None = None, *,
                     min_parallax_deg: float = 1.0, refine_iterations: int = 3) -> Triangulation:
    """Triangulate `count` points from rays: observation k is a ray from centres[k] along the unit
    world direction directions[k], belonging to point point[k] (0 <= point[k] < count).

    Points with fewer than two rays come back invalid (nan).
    """
    c = np.asarray(centres, float).reshape(-1, 3)
    d = np.asarray(directions, float).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    idx = np.asarray(point, np.int64).reshape(-1)
    if not (len(c) == len(d) == len(idx)):
        raise ValueError(f"rays disagree: centres {c.shape}, directions {d.shape}, point {idx.shape}")
    M = int(count if count is not None else (idx.max() + 1 if len(idx) else 0))
    n_obs = np.bincount(idx, minlength=M)
    # Midpoint: sum (I - d d^T) X = sum (I - d d^T) c.
    P = np.eye(3) - d[:, :, None] * d[:, None, :]
    A = _sum_by(idx, P, M)
    b = _sum_by(idx, np.einsum("kij,kj->ki", P, c), M)
    ok = n_obs >= 2
    A[~ok] = np.eye(3)
    b[~ok] = 0.0
    # Near-parallel rays make A singular: regularise the solve, parallax rejects them afterwards.
    X = np.linalg.solve(A + 1e-12 * np.eye(3), b[..., None])[..., 0]
    for _ in range(refine_iterations):
        X = _refine_angular(c, d, idx, X, M, ok)
    v = X[idx] - c
    s = np.einsum("ki,ki->k", v, d)
    in_front = np.ones(M, bool)
    np.logical_and.at(in_front, idx, s > 0)
    # Parallax: the widest angle between the rays of a point, approximated by the widest angle to
    # the ray of its first observation (within a factor of two of the true widest angle).
    r = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)
    first = np.full(M, -1)
    order = np.arange(len(idx))[::-1]
    first[idx[order]] = order  # the last write wins: the first observation of each point
    min_cos = np.ones(M)
    np.minimum.at(min_cos, idx, np.einsum("ki,ki->k", r, r[first[idx]]))
    parallax = np.degrees(np.arccos(np.clip(min_cos, -1.0, 1.0)))
    # atan2 of |cross| and dot: arccos loses precision for tiny angles.
    ang = np.arctan2(np.linalg.norm(np.cross(r, d), axis=1), np.einsum("ki,ki->k", r, d))
    error = np.zeros(M)
    np.maximum.at(error, idx, np.degrees(ang))
    finite = np.all(np.isfinite(X), axis=1)
    valid = ok & in_front & finite & (parallax >= min_parallax_deg)
    X = np.where(ok[:, None], X, np.nan)
    return Triangulation(X, valid, parallax, in_front & ok, error)


def _refine_angular(c, d, idx, X, M, ok):
    """One Gauss-Newton step on the tangent-plane error (I - b b^T) d of each ray, b = (X - c)/|X - c|:
    the residual is d's component off the predicted bearing, an angle for small errors."""
    v = X[idx] - c
    n = np.linalg.norm(v, axis=1)
    n = np.where(n > 1e-12, n, 1e-12)
    b = v / n[:, None]
    e = d - np.einsum("ki,ki->k", d, b)[:, None] * b  # residual: observed minus predicted, in the tangent plane
    # d b / d X = (I - b b^T) / n; the residual e ~ d - b to first order in the tangent plane.
    J = (np.eye(3) - b[:, :, None] * b[:, None, :]) / n[:, None, None]
    H = _sum_by(idx, J @ J, M)  # J is symmetric: J^T J, without a transposed copy or numpy's slow path for a view
    g = _sum_by(idx, np.einsum("kji,kj->ki", J, e), M)
    H[~ok] = np.eye(3)
    g[~ok] = 0.0
    step = np.linalg.solve(H + 1e-9 * np.einsum("mii->m", H)[:, None, None] * np.eye(3), g[..., None])[..., 0]
    new = X + step
    return np.where(np.all(np.isfinite(new), axis=1, keepdims=True), new, X)


def triangulate_two_view(R: np.ndarray, t: np.ndarray, bearings_i: np.ndarray, bearings_j: np.ndarray, *,
                         min_parallax_deg: float = 1.0) -> Triangulation:
    """Points in camera i's frame from bearings in views i and j, where X_j = R X_i + t (the front
    end's relative pose convention). The scale is that of t."""
    R, t = np.asarray(R, float), np.asarray(t, float)
    bi = np.asarray(bearings_i, float).reshape(-1, 3)
    bj = np.asarray(bearings_j, float).reshape(-1, 3)
    n = len(bi)
    # Camera j in camera i's frame: centre -R^T t, directions R^T eta_j.
    centres = np.concatenate([np.zeros((n, 3)), np.tile(-R.T @ t, (n, 1))])
    dirs = np.concatenate([bi, bj @ R])
    idx = np.concatenate([np.arange(n), np.arange(n)])
    return triangulate_rays(centres, dirs, idx, n, min_parallax_deg=min_parallax_deg)


__all__ = ["Triangulation", "triangulate_rays", "triangulate_two_view"]
