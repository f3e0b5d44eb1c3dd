"""Closed-form alignment of corresponding point sets (Umeyama 1991; Horn's method without scale)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Alignment(NamedTuple):
    """`target ≈ scale * rotation @ source + translation`; unpacks as `R, t, s`."""

    rotation: np.ndarray  # (3, 3), det +1
    translation: np.ndarray  # (3,)
    scale: float

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map (..., 3) points of the source frame into the target frame."""
        return self.scale * np.asarray(points, float) @ self.rotation.T + self.translation

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous form of the transform."""
        T = np.eye(4)
        T[:3, :3] = self.scale * self.rotation
        T[:3, 3] = self.translation
        return T


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool = False) -> Alignment:
    """Least-squares rigid (SE(3)) or similarity (Sim(3)) transform taking `source` onto `target`.

    Minimises sum |target_i - (s R source_i + t)|^2 over N >= 1 corresponding (N, 3) points.
    With `with_scale=False` the scale is fixed at 1. Degenerate sets (collinear points, as
    in a straight pipe) leave the rotation about the line undetermined; any minimiser is
    returned, so the residuals remain correct.
    """
    x = np.asarray(source, dtype=float)
    y = np.asarray(target, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape != y.shape or len(x) == 0:
        raise ValueError(f"expected two non-empty (N, 3) arrays of equal shape, got {x.shape} and {y.shape}")
    mu_x, mu_y = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mu_x, y - mu_y
    sigma = yc.T @ xc / len(x)
    U, d, Vt = np.linalg.svd(sigma)
    S = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2] = -1.0  # the best orthogonal matrix is a reflection: flip the weakest direction
    R = (U * S) @ Vt
    scale = 1.0
    if with_scale:
        var_x = float(np.mean(np.sum(xc**2, axis=1)))
        scale = float(np.dot(d, S) / var_x) if var_x > 0 else 1.0
    t = mu_y - scale * R @ mu_x
    return Alignment(R, t, scale)
