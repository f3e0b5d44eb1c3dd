"""Angular errors of bearings and a Huber-weighted Levenberg-Marquardt over a pose (right perturbation).

Shared by the loop-closure pair pose (place_match) and the resection of a keyframe against its
scene points (resection): errors are measured on the view sphere, so they mean the same for any
central camera, at any angle from its axis.
"""

from __future__ import annotations

import numpy as np

from pipemap.solvers import huber_irls, levenberg_marquardt

_I3 = np.eye(3)


def tangent_bases(b: np.ndarray) -> np.ndarray:
    """(M, 3, 2) orthonormal bases of the tangent planes of unit bearings b (M, 3)."""
    helper = np.where(np.abs(b[:, :1]) < 0.9, _I3[0], _I3[1])
    e1 = np.cross(b, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(b, e1)], axis=-1)


def angular_residuals(points: np.ndarray, bearings: np.ndarray, bases: np.ndarray, jacobian: bool = False):
    """Tangent-plane error (M, 2) of camera-frame points against observed bearings (about the angle,
    radians), and its derivative with respect to the point (M, 2, 3)."""
    norm = np.linalg.norm(points, axis=1)
    unit = points / norm[:, None]
    r = np.einsum("mik,mi->mk", bases, unit)
    if not jacobian:
        return r
    proj = (_I3 - unit[:, :, None] * unit[:, None, :]) / norm[:, None, None]
    return r, np.einsum("mik,mij->mkj", bases, proj)


def refine_huber(problem, huber: float, iterations: int = 30):
    """Levenberg-Marquardt with Huber IRLS weights on each bearing's angular error. `problem` has
    residuals(jacobian=True) -> (2M,) residuals and their (2M, 6) Jacobian at delta = 0, and
    moved(delta) -> the problem at the perturbed pose."""
    return levenberg_marquardt(lambda p: p.residuals(jacobian=True), lambda p, d: p.moved(d), problem,
                               iterations=iterations, cost=huber_irls(huber, group=2)).state


__all__ = ["tangent_bases", "angular_residuals", "refine_huber"]
