"""The pipe frame of the 2010 report (section 2, eq. 1-2) and the scene-point constraint (section 5.2).

Pipe frame: X = (X, Y, h) with h along the axis and X^2 + Y^2 = r^2 on the wall. A camera pose is
(R, C) with R mapping camera axes to pipe axes and C the camera centre, so a point seen at X_c
in the camera lies at X = R X_c + C (the report's P^-1, eq. 4-5). The report's initial pose
(eq. 18, 45) looks straight up with image x down the pipe:

    R0 = [[0, 1, 0], [0, 0, 1], [1, 0, 0]]   (camera y -> X, camera z -> Y, camera x -> h).

A keypoint's bearing eta meets the wall at X = C + kappa R eta, kappa the positive root of eq. 37;
pipemap.geometry.cylinder.Cylinder.intersect_bearings solves it. Wall coordinates are (h, rho)
with rho = r phi and phi = atan2(-X, Y): 0 where the initial camera looks (up, +Y) and
increasing clockwise seen looking along +h (towards -X); the bottom of the pipe, never in view
of a camera looking up, is the seam at +-pi r (the report's footnote 9 offset).

Pose updates are right perturbations (pipemap.geometry.se3.retract): R <- R exp(w),
C <- C + R v for delta = (v, w) in the camera's own axes.
"""

from __future__ import annotations

import numpy as np

from pipemap.geometry.cylinder import Cylinder
from pipemap.geometry.rotations import skew

R0 = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
E_H = np.array([0.0, 0.0, 1.0])


def pipe_cylinder(radius: float) -> Cylinder:
    return Cylinder(np.zeros(3), E_H, radius)


def wall_points(R: np.ndarray, C: np.ndarray, bearings: np.ndarray, radius: float,
                jacobian: bool = False):
    """Eqs. 35-39: where the bearings (N, 3) of a camera (R, C) meet the wall.

    Returns points (N, 3), valid (N,) and, with `jacobian`, dX / d delta (N, 3, 6) for the right
    perturbation delta = (v, w) of the pose. From the implicit constraint |q| = r on the radial
    part q = (X, Y) of X = C + kappa d (d = R eta): d kappa = -q.(dC + kappa dd)_xy / q.d_xy."""
    b = np.asarray(bearings, float)
    X, kappa, valid = pipe_cylinder(radius).intersect_bearings(R, C, b)
    if not jacobian:
        return X, valid
    d = b @ R.T
    q = X[:, :2]
    denom = np.einsum("ni,ni->n", q, d[:, :2])
    denom = np.where(np.abs(denom) > 1e-12, denom, 1e-12)
    # dC/dv = R; dd/dw = -R [eta]x, so d(C + kappa d) before the kappa change:
    direct = np.empty((len(b), 3, 6))
    direct[:, :, :3] = R
    direct[:, :, 3:] = -kappa[:, None, None] * (R @ skew(b))
    dkappa = -np.einsum("ni,nij->nj", q, direct[:, :2, :]) / denom[:, None]
    J = direct + d[:, :, None] * dkappa[:, None, :]
    return X, valid, J


def wall_offset_jacobian(X: np.ndarray, R: np.ndarray, bearings: np.ndarray) -> np.ndarray:
    """dX / dC (N, 3, 3) of wall points X for a change of the camera centre C in pipe axes."""
    d = np.asarray(bearings, float) @ R.T
    q = X[:, :2]
    denom = np.einsum("ni,ni->n", q, d[:, :2])
    denom = np.where(np.abs(denom) > 1e-12, denom, 1e-12)
    dkappa = np.zeros((len(X), 3))
    dkappa[:, :2] = -q / denom[:, None]
    return np.eye(3)[None] + d[:, :, None] * dkappa[:, None, :]


def wall_coords(X: np.ndarray, radius: float, jacobian: bool = False):
    """(h, rho) (N, 2) of wall points and, with `jacobian`, d(h, rho)/dX (N, 2, 3)."""
    X = np.asarray(X, float)
    hr = np.stack([X[:, 2], radius * np.arctan2(-X[:, 0], X[:, 1])], axis=-1)
    if not jacobian:
        return hr
    q2 = np.maximum(X[:, 0] ** 2 + X[:, 1] ** 2, 1e-300)
    J = np.zeros((len(X), 2, 3))
    J[:, 0, 2] = 1.0
    J[:, 1, 0] = -radius * X[:, 1] / q2
    J[:, 1, 1] = radius * X[:, 0] / q2
    return hr, J


def wall_from_coords(hr: np.ndarray, radius: float) -> np.ndarray:
    """The wall points (..., 3) of wall coordinates (..., 2) = (h, rho)."""
    hr = np.asarray(hr, float)
    phi = hr[..., 1] / radius
    return np.stack([-radius * np.sin(phi), radius * np.cos(phi), hr[..., 0]], axis=-1)


def initial_pose(cx: float, cy: float) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 45: the first camera looks up (R0) from (C_X, C_Y, 0)."""
    return R0.copy(), np.array([cx, cy, 0.0])


def rotation_from_travel(travel: np.ndarray) -> np.ndarray:
    """Camera -> pipe rotation of a camera travelling along the pipe axis in the direction `travel` (its own
    axes): h along the travel, and the optical axis in the (Y, h) plane on the +Y side (the report's
    convention for R0, which this gives for a travel along image x)."""
    d = np.asarray(travel, float) / np.linalg.norm(travel)
    look = np.array([0.0, 0.0, 1.0]) - d[2] * d
    n = np.linalg.norm(look)
    if n < 1e-6:
        raise ValueError("the camera travels along its optical axis: it looks along the pipe, not at the wall")
    Y = look / n
    return np.stack([np.cross(Y, d), Y, d])


def wall_distance(R: np.ndarray, C: np.ndarray, radius: float) -> float:
    """Distance from the camera (R, C) to the wall along its optical axis: what sets the metric scale of
    its image motion."""
    X, valid = wall_points(R, C, np.array([[0.0, 0.0, 1.0]]), radius)
    return float(np.linalg.norm(X[0] - C)) if valid[0] else float("nan")
