"""Rigid poses as (R, t) arrays, and the right perturbation the back end optimises them on.

A pose is T_wc = (R, t): `R` maps camera axes to world axes, `t` is the camera centre, so a world
point X is seen at X_c = R^T (X - t). Arrays are vectorised: R (..., 3, 3), t (..., 3).

The update of a pose by a 6-vector delta = (rho, phi) is the right perturbation

    R <- R exp(phi),   t <- t + R rho,

i.e. rho and phi are a translation and a rotation vector in the camera's own axes. Its derivative
at delta = 0 is simple: d X_c / d rho = -I, d X_c / d phi = [X_c]x (see `camera_point_jacobian`).
"""

from __future__ import annotations

import numpy as np

from pipemap.geometry.rotations import exp_so3, skew


def as_rt(poses) -> tuple[np.ndarray, np.ndarray]:
    """(..., 4, 4) matrices or an (R, t) pair -> (R (..., 3, 3), t (..., 3)) as float copies."""
    if isinstance(poses, (tuple, list)) and len(poses) == 2:
        R, t = (np.array(p, dtype=float) for p in poses)
    else:
        T = np.asarray(poses, dtype=float)
        if T.shape[-2:] != (4, 4):
            raise ValueError(f"poses must be (..., 4, 4) matrices or an (R, t) pair, got shape {T.shape}")
        R, t = T[..., :3, :3].copy(), T[..., :3, 3].copy()
    if R.shape[-2:] != (3, 3) or t.shape[-1:] != (3,) or R.shape[:-2] != t.shape[:-1]:
        raise ValueError(f"rotations {R.shape} and translations {t.shape} disagree")
    return R, t


def to_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(R, t) -> homogeneous (..., 4, 4)."""
    R, t = np.asarray(R, float), np.asarray(t, float)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T^-1 = (R^T, -R^T t)."""
    Rt = np.swapaxes(R, -1, -2)
    return Rt, -np.einsum("...ij,...j->...i", Rt, t)


def compose(R1: np.ndarray, t1: np.ndarray, R2: np.ndarray, t2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T1 T2: apply T2 first, then T1."""
    return R1 @ R2, np.einsum("...ij,...j->...i", R1, t2) + t1


def world_to_camera(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """X_c = R^T (X - t), broadcast over leading axes."""
    return np.einsum("...ji,...j->...i", R, np.asarray(X, float) - t)


def retract(R: np.ndarray, t: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply the right perturbation delta = (rho, phi) (..., 6): R exp(phi), t + R rho."""
    delta = np.asarray(delta, float)
    return R @ exp_so3(delta[..., 3:]), t + np.einsum("...ij,...j->...i", R, delta[..., :3])


def camera_point_jacobian(Xc: np.ndarray) -> np.ndarray:
    """d X_c / d delta (..., 3, 6) for X_c = R^T (X - t) under `retract`: [-I, [X_c]x].

    (The derivative with respect to the world point is simply R^T.)
    """
    Xc = np.asarray(Xc, float)
    J = np.empty(Xc.shape[:-1] + (3, 6))
    J[..., :3] = -np.eye(3)
    J[..., 3:] = skew(Xc)
    return J
