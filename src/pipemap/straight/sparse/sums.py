"""The S(g) sums of the 2010 report (eq. 41) and the error they give a pose (eqs. 42-44).

Every world point g has n estimates of its wall coordinates (h, rho), one per keyframe that saw
it; S(g) = [n, sum h, sum h^2, sum rho, sum rho^2]. A new estimate (h^, rho^) costs

    eps_g = n h^2 - 2 h^ sum h + sum h^2 + n rho^2 - 2 rho^ sum rho + sum rho^2        (eq. 44)
          = n (h^ - mean h)^2 + n (rho^ - mean rho)^2 + (spread of the stored estimates),

so least squares on the residuals sqrt(n) (h^ - mean h), sqrt(n) (rho^ - mean rho) minimises
eq. 42 exactly; the spread does not depend on the new pose.
"""

from __future__ import annotations

import numpy as np


class WallSums:
    """S(g) for every global index g, grown on demand."""

    def __init__(self, capacity: int = 1024):
        self.S = np.zeros((capacity, 5))
        self.count = 0  # global indices handed out

    def new_ids(self, n: int) -> np.ndarray:
        ids = np.arange(self.count, self.count + n)
        self.count += n
        if self.count > len(self.S):
            grown = np.zeros((max(2 * len(self.S), self.count), 5))
            grown[: len(self.S)] = self.S
            self.S = grown
        return ids

    def add(self, gid: np.ndarray, hr: np.ndarray, sign: float = 1.0) -> None:
        """Add (sign = 1) or remove (sign = -1) estimates hr (N, 2) of the points gid (N,)."""
        gid = np.asarray(gid, int)
        hr = np.asarray(hr, float)
        ok = np.all(np.isfinite(hr), axis=1)
        g, h, r = gid[ok], hr[ok, 0], hr[ok, 1]
        rows = np.stack([np.ones_like(h), h, h * h, r, r * r], axis=-1) * sign
        np.add.at(self.S, g, rows)
        # removing every estimate of a point must leave it exactly empty
        empty = self.S[g, 0] < 0.5
        self.S[g[empty]] = 0.0

    def n(self, gid: np.ndarray) -> np.ndarray:
        return self.S[np.asarray(gid, int), 0]

    def means(self, gid: np.ndarray) -> np.ndarray:
        s = self.S[np.asarray(gid, int)]
        n = np.maximum(s[:, 0], 1.0)
        return np.stack([s[:, 1] / n, s[:, 3] / n], axis=-1)

    def epsilon(self, gid: np.ndarray, hr: np.ndarray) -> np.ndarray:
        """Eq. 44 for each estimate hr (N, 2) of the points gid, straight from S(g)."""
        s = self.S[np.asarray(gid, int)]
        h, r = hr[:, 0], hr[:, 1]
        return (s[:, 0] * h * h - 2 * h * s[:, 1] + s[:, 2]) + (s[:, 0] * r * r - 2 * r * s[:, 3] + s[:, 4])

    def residuals(self, gid: np.ndarray, hr: np.ndarray, J_hr: np.ndarray | None = None):
        """Residuals (2M,) of the estimates whose point has stored estimates (M of N), their
        Jacobian (2M, P) from d hr / d params (N, 2, P), and the mask of those M."""
        n = self.n(gid)
        used = n > 0
        w = np.sqrt(n[used])[:, None]
        r = (w * (hr[used] - self.means(gid[used]))).ravel()
        if J_hr is None:
            return r, None, used
        J = (w[:, :, None] * J_hr[used]).reshape(-1, J_hr.shape[-1])
        return r, J, used
