"""Angular errors of bearings and a Huber-weighted Levenberg-Marquardt over a pose (right perturbation).

Shared by the loop-closure pair pose (place_match) and the resection of a keyframe against its
scene points (resection): errors are measured on the view sphere, so they mean the same for any
central camera, at any angle from its axis.
"""

from __future__ import annotations

import numpy as np

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


def huber_cost(a: np.ndarray, k: float) -> tuple[np.ndarray, np.ndarray]:
    """Cost and IRLS weight of errors a >= 0."""
    return np.where(a <= k, a * a, 2 * k * a - k * k), np.where(a <= k, 1.0, k / np.maximum(a, 1e-300))


def refine_huber(problem, huber: float, iterations: int = 30):
    """Levenberg-Marquardt with Huber IRLS weights on each bearing's angular error. `problem` has
    residuals(jacobian=False) -> (2M,) residuals [and their (2M, 6) Jacobian at delta = 0] and
    moved(delta) -> the problem at the perturbed pose."""
    r, J = problem.residuals(jacobian=True)
    cost = huber_cost(np.linalg.norm(r.reshape(-1, 2), axis=1), huber)[0].sum()
    lam = 1e-3
    for _ in range(iterations):
        w = np.repeat(huber_cost(np.linalg.norm(r.reshape(-1, 2), axis=1), huber)[1], 2)
        H = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        while lam < 1e8:
            step = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), -g)
            trial = problem.moved(step)
            r_new = trial.residuals()
            c_new = huber_cost(np.linalg.norm(r_new.reshape(-1, 2), axis=1), huber)[0].sum()
            if c_new <= cost:
                break
            lam *= 10.0
        else:
            return problem
        done = cost - c_new <= 1e-12 * cost or np.linalg.norm(step) < 1e-12
        problem, cost, lam = trial, c_new, max(lam * 0.3, 1e-9)
        r, J = problem.residuals(jacobian=True)
        if done:
            break
    return problem


__all__ = ["tangent_bases", "angular_residuals", "huber_cost", "refine_huber"]
