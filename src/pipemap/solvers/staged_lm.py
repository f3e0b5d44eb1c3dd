"""Levenberg-Marquardt in stages separated by outlier passes (fisheye paper III-C: Huber weights on
every term, MAD outlier removal "at multiple stages"), shared by the window and the tee solves.

The problem supplies its pieces through a context: whatever a stage holds fixed (the inlier
observations, and for a tee which cylinder each point belongs to). Within a stage, iteratively
re-weighted LM steps run until the cost falls by less than `stage_ftol` of itself (`ftol` in the
last stage); between stages `reject(state, context)` gives the next context, and the stages end
when it no longer changes or after `outlier_passes`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

FTOL = 1e-6  # the final stage ends when an iteration lowers the cost by less than this fraction
STAGE_FTOL = 1e-3  # ... and a stage before an outlier pass at this fraction


@dataclass
class StagedRun:
    state: Any
    context: Any
    cost_history: list[float]
    iterations: int
    converged: bool
    outlier_counts: list[int] = field(default_factory=list)


def solve_in_stages(state, context, *, cost: Callable, linearise: Callable, solve: Callable, step: Callable,
                    reject: Callable, same: Callable, outliers: Callable, max_iterations: int,
                    outlier_passes: int) -> StagedRun:
    """cost(state, context) -> float; linearise(state, context) -> the normal equations of a stage
    (built per iteration); solve(equations, lam) -> step or None; step(state, delta) -> state;
    reject(state, context) -> next context; same(a, b) -> bool; outliers(context) -> count."""
    c0 = cost(state, context)
    history, counts = [c0], []
    current = c0
    lam, iterations, passes, settled = 1e-4, 0, 0, False
    converged = False
    while True:
        last = settled or passes >= outlier_passes
        tol = FTOL if last else STAGE_FTOL
        budget = max_iterations - iterations - (0 if last else outlier_passes - passes)
        converged = False
        for _ in range(max(budget, 1)):
            if iterations >= max_iterations:
                break
            eq = delta = None  # the last step's equations let go before the next are built
            eq = linearise(state, context)
            accepted = False
            while lam < 1e12:
                delta = solve(eq, lam)
                if delta is not None:
                    trial = step(state, delta)
                    c = cost(trial, context)
                    if np.isfinite(c) and c < current:
                        accepted = True
                        break
                lam *= 10.0
            iterations += 1
            if not accepted:  # no descent direction left: a minimum
                converged = True
                history.append(current)
                break
            small = current - c <= tol * current
            state, current, lam = trial, c, max(lam / 3.0, 1e-12)
            history.append(current)
            if small:
                converged = True
                break
        if last:
            break
        new = reject(state, context)
        passes += 1
        counts.append(int(outliers(new)))
        settled = bool(same(new, context))
        context = new
        current = cost(state, context)
        lam = max(lam, 1e-4)
    return StagedRun(state, context, history, iterations, converged, counts)


__all__ = ["StagedRun", "solve_in_stages", "FTOL", "STAGE_FTOL"]
