"""Synthetic fisheye tracks of wall points, shared by the junction and elbow solve tests."""

from __future__ import annotations

import numpy as np


def tracked_runs(cam, R: np.ndarray, t: np.ndarray, X: np.ndarray, rng: np.random.Generator):
    """Each point of X (M, 3) observed along a run of 3-8 consecutive keyframes (R (K, 3, 3), t (K, 3)) that see it
    (beyond 20 deg colatitude, within 0.9 m): (keyframe (N,), point (N,) renumbered over the points seen, exact
    pixels (N, 2), the indices of those points into X)."""
    Xc = np.einsum("nji,nmj->nmi", R, X[None] - t[:, None])
    uv, valid = cam.project(Xc)
    valid &= (cam.colatitude(Xc) > np.radians(20)) & (np.linalg.norm(Xc, axis=-1) < 0.9)
    cams, pts, pix = [], [], []
    for m in range(len(X)):
        seen = np.flatnonzero(valid[:, m])
        if len(seen) < 3:
            continue
        L = min(rng.integers(3, 9), len(seen))
        start = rng.integers(0, len(seen) - L + 1)
        run = seen[start:start + L]
        cams.append(run)
        pts.append(np.full(L, m))
        pix.append(uv[run, m])
    cams, pts, pix = np.concatenate(cams), np.concatenate(pts), np.concatenate(pix)
    used = np.unique(pts)
    remap = np.full(len(X), -1)
    remap[used] = np.arange(len(used))
    return cams, remap[pts], pix, used
