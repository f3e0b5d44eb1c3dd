"""Synthetic fisheye tracks of wall points, shared by the bundle, junction and elbow solve tests."""

from __future__ import annotations

import numpy as np


def tracked_runs(cam, R: np.ndarray, t: np.ndarray, X: np.ndarray, rng: np.random.Generator,
                 track: tuple[int, int] = (3, 8), min_seen: int = 3, min_colatitude_deg: float = 20.0,
                 max_range_m: float | None = 0.9):
    """Each point of X (M, 3) observed along a run of track[0]-track[1] consecutive keyframes (R (K, 3, 3), t (K, 3))
    that see it (beyond min_colatitude_deg, within max_range_m; points seen by fewer than min_seen are left out):
    (keyframe (N,), point (N,) renumbered over the points seen, exact pixels (N, 2), the indices of those points
    into X)."""
    Xc = np.einsum("nji,nmj->nmi", R, X[None] - t[:, None])
    uv, valid = cam.project(Xc)
    valid &= cam.colatitude(Xc) > np.radians(min_colatitude_deg)
    if max_range_m is not None:
        valid &= np.linalg.norm(Xc, axis=-1) < max_range_m
    cams, pts, pix = [], [], []
    for m in range(len(X)):
        seen = np.flatnonzero(valid[:, m])
        if len(seen) < min_seen:
            continue
        L = min(rng.integers(track[0], track[1] + 1), len(seen))
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
