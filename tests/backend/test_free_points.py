"""Points triangulated again without the cylinder term (backend/free_points.py)."""

from __future__ import annotations

import numpy as np

from pipemap.backend import free_points as fp
from pipemap.frontend.tracks import Keyframe


def _keyframes(rng, n_kf=12, n_pts=300):
    """Cameras along a pipe axis (z) looking down it, wall points of a 0.2 m pipe, each seen by a run of
    keyframes with bearings off by about 0.006 deg (0.1 mrad)."""
    phi = rng.uniform(0, 2 * np.pi, n_pts)
    X = np.stack([0.2 * np.cos(phi), 0.2 * np.sin(phi), rng.uniform(0.3, 1.5, n_pts)], axis=1)
    first = rng.integers(0, n_kf - 3, n_pts)
    poses, kfs = np.tile(np.eye(4), (n_kf, 1, 1)), []
    for k in range(n_kf):
        poses[k, 2, 3] = 0.05 * k
        seen = np.flatnonzero((first <= k) & (k < first + 4) & (X[:, 2] > poses[k, 2, 3] + 0.1))
        b = X[seen] - poses[k, :3, 3]
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        b += rng.normal(0, 1e-4, b.shape)
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        kfs.append(Keyframe(k, k, float(k), np.zeros((len(seen), 2)), b, seen.astype(np.int64) + 1000,
                            np.ones(len(seen), bool), np.zeros(len(seen), bool), np.eye(3), np.zeros(3), True))
    return kfs, poses, X


def test_points_triangulated_in_parts_are_the_whole_solve(monkeypatch):
    """free_points triangulates POINTS_AT_ONCE points at a time (all of a long run's at once took hundreds of
    MB): the same points and validity as one solve over all of them, and near the true wall points."""
    rng = np.random.default_rng(4)
    kfs, poses, X = _keyframes(rng)
    tracks = np.arange(1000, 1000 + len(X))[::-1]  # the wanted order is the caller's, not the track ids'
    whole, valid = fp.free_points(kfs, poses, tracks, min_parallax_deg=1.0, max_ray_error_deg=0.5)
    monkeypatch.setattr(fp, "POINTS_AT_ONCE", 17)
    parts, valid_parts = fp.free_points(kfs, poses, tracks, min_parallax_deg=1.0, max_ray_error_deg=0.5)
    np.testing.assert_array_equal(valid_parts, valid)
    np.testing.assert_allclose(parts[valid], whole[valid], rtol=0, atol=1e-12)
    assert valid.sum() > 0.8 * len(X)
    truth = X[tracks - 1000]
    assert np.median(np.linalg.norm(whole[valid] - truth[valid], axis=1)) < 2e-3
