"""Levenberg-Marquardt with optional iteratively re-weighted robust costs, for problems whose normal
equations are small: a pose, a cylinder, a keyframe's height, an offset over a batch (the bundle
adjustments, whose normal equations are large and structured, use staged_lm with the Schur complement).

Marquardt's damping scales the normal equations' diagonal, so the step is invariant to the units of
each parameter; a step is kept only when it does not raise the cost. The problem is given as
`evaluate(state) -> (r, J)` (J dense or scipy-sparse, (n, p)) and `apply(state, step) -> state`, so a
state may live on a manifold (rotations) and be perturbed in its tangent space.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp

INITIAL_DAMPING = 1e-4
MIN_DAMPING, MAX_DAMPING = 1e-12, 1e12


@dataclass
class LMResult:
    state: Any
    cost: float
    iterations: int


def least_squares_cost(r: np.ndarray) -> tuple[float, np.ndarray]:
    """Plain least squares: cost |r|^2, every residual weighted 1."""
    return float(r @ r), np.ones(len(r))


def levenberg_marquardt(evaluate: Callable, apply: Callable, state, *, iterations: int = 20,
                        cost: Callable[[np.ndarray], tuple[float, np.ndarray]] = least_squares_cost,
                        tolerance: float = 1e-12) -> LMResult:
    """Minimise cost(r(state)). `cost(r) -> (total, weights)` gives the robust total and the IRLS weight
    of every residual for the next step (solvers.robust's Huber weights make w r^2 the Huber cost to first
    order). Stops after `iterations`, when a step lowers the cost by no more than `tolerance` of it, or when
    no damping finds a step that does not raise it."""
    r, J = evaluate(state)
    total, w = cost(r)
    lam, it = INITIAL_DAMPING, 0
    for it in range(1, iterations + 1):
        H, g = _normal_equations(J, r, w)
        diag = np.diag(H) + 1e-12 * (np.trace(H) / max(len(H), 1) + 1e-30)
        accepted = done = False
        while lam < MAX_DAMPING:
            try:
                step = np.linalg.solve(H + lam * np.diag(diag), -g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            trial = apply(state, step)
            r_new, J_new = evaluate(trial)
            new_total, w_new = cost(r_new)
            if np.isfinite(new_total) and new_total <= total:
                done = total - new_total <= tolerance * total + 1e-300
                state, r, J, total, w, accepted = trial, r_new, J_new, new_total, w_new, True
                lam = max(lam * 0.1, MIN_DAMPING)
                break
            lam *= 10.0
        if not accepted or done:
            break
    return LMResult(state, float(total), it)


def _normal_equations(J, r: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if sp.issparse(J):
        WJ = sp.diags(w) @ J
        return np.asarray((J.T @ WJ).todense()), np.asarray(WJ.T @ r).ravel()
    WJ = w[:, None] * J
    return J.T @ WJ, WJ.T @ r


__all__ = ["LMResult", "levenberg_marquardt", "least_squares_cost", "INITIAL_DAMPING"]
