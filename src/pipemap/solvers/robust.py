"""Huber weighting and MAD outlier rejection (fisheye paper III-C).

Iteratively re-weighted least squares: a residual of size a (a norm for a 2D reprojection error, an
absolute value for a distance) costs huber_cost(a, k) = a^2 below the threshold k and 2 k a - k^2 above,
and is weighted by huber_weights(a, k) = min(1, k / a) in the next Gauss-Newton step, whose weighted
squared residual w a^2 equals the Huber cost to first order.
"""

from __future__ import annotations

import numpy as np

MAD_TO_SIGMA = 1.4826  # sigma of a normal distribution / its median absolute deviation


def huber_weights(a: np.ndarray, k: float) -> np.ndarray:
    """IRLS weights min(1, k / a) of non-negative residual sizes a."""
    a = np.asarray(a, float)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-300))


def huber_cost(a: np.ndarray, k: float) -> np.ndarray:
    """Huber cost of non-negative residual sizes a: a^2 inside k, 2 k a - k^2 outside (continuous, C1)."""
    a = np.asarray(a, float)
    return np.where(a <= k, a * a, 2.0 * k * a - k * k)


def huber_irls(k: float, group: int = 1):
    """The Huber cost for solvers.lm: cost(r) -> (total, weights) of residuals r whose sizes are |r|, or the
    norms of consecutive groups of `group` components (a 2D reprojection or tangent-plane error)."""
    def cost(r: np.ndarray) -> tuple[float, np.ndarray]:
        a = np.abs(r) if group == 1 else np.linalg.norm(r.reshape(-1, group), axis=1)
        w = huber_weights(a, k)
        return float(huber_cost(a, k).sum()), (w if group == 1 else np.repeat(w, group))
    return cost


def _median(x: np.ndarray, axis, keepdims: bool):
    """np.median of a float array, by one partition along `axis` where nothing is NaN: the same values (the mean
    of the two middle ones is their half-sum either way), without np.median's overhead on many short rows."""
    if axis is None or x.shape[axis] == 0 or np.isnan(x).any():
        return np.median(x, axis=axis, keepdims=keepdims)
    n = x.shape[axis]
    lo, hi = (n - 1) // 2, n // 2
    part = np.partition(x, sorted({lo, hi}), axis=axis)
    m = 0.5 * (np.take(part, lo, axis=axis) + np.take(part, hi, axis=axis))
    return np.expand_dims(m, axis) if keepdims else m


def mad_sigma(x: np.ndarray, centre: float | np.ndarray | None = None, axis=None, keepdims: bool = False):
    """Robust standard deviation 1.4826 x the median absolute deviation of x from `centre` (default: the
    median; 0 for sizes such as distances or residual norms, whose spread is measured from zero)."""
    x = np.asarray(x, float)
    if centre is None:
        centre = _median(x, axis, True)
    return MAD_TO_SIGMA * _median(np.abs(x - centre), axis, keepdims)


def mad_inliers(errors: np.ndarray, k: float, reference: np.ndarray | None = None, floor: float = 0.0) -> np.ndarray:
    """Which rows of signed errors (n,) or (n, d) lie within k robust sigmas of the median.

    The median and the MAD are taken over all components of the rows selected by `reference`
    (default: all rows), so a pass can re-admit rows rejected earlier. A row is an inlier when every
    component is within max(k * 1.4826 * MAD, floor) of the median; the floor keeps exact data from
    being rejected on round-off.
    """
    e = np.asarray(errors, float)
    e2 = e.reshape(len(e), -1)
    ref = e2 if reference is None else e2[np.asarray(reference, bool)]
    if ref.size == 0:
        return np.ones(len(e), bool)
    med = np.median(ref)
    bound = max(k * mad_sigma(ref, med), floor)
    return np.all(np.abs(e2 - med) <= bound, axis=1)
