"""Central differences, for checking hand-written Jacobians."""

from __future__ import annotations

import numpy as np


def numerical(f, x, eps=1e-6):
    """Central differences of f (returning (M,)) with respect to each entry of x."""
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e.flat[i] = eps
        cols.append((f(x + e) - f(x - e)) / (2 * eps))
    return np.stack(cols, -1)
