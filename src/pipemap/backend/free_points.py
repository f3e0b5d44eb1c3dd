"""The scene points triangulated again from their tracks with the keyframe poses held fixed and no cylinder
term: the window solves pull every point towards its section's cylinder (tau), which would flatten the
very ovality and dents a deformation measurement looks for. The poses keep what the cylinder term gave
them (scale, straightness); the points answer to their rays alone."""

from __future__ import annotations

import numpy as np

from pipemap.backend.triangulate import triangulate_rays
from pipemap.frontend.tracks import Keyframe

# Points triangulated at a time: all of paper-loop route A's 245,000 at once took 520 MB of temporaries.
POINTS_AT_ONCE = 32768


def free_points(keyframes: list[Keyframe], poses: np.ndarray, track_ids: np.ndarray, *, min_parallax_deg: float,
                max_ray_error_deg: float, min_views: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(points (M, 3), valid (M,)) for the tracks `track_ids`, from every keyframe that observes them (poses
    (N, 4, 4) T_wc of `keyframes`). A point is valid with at least `min_views` rays, the parallax, and no ray
    farther than `max_ray_error_deg` from it."""
    wanted = np.asarray(track_ids, np.int64)
    order = np.argsort(wanted)
    ids, centres, dirs = [], [], []
    for k, kf in enumerate(keyframes):
        if len(kf.track_ids) == 0:
            continue
        p = np.clip(np.searchsorted(wanted[order], kf.track_ids), 0, max(len(wanted) - 1, 0))
        ok = wanted[order][p] == kf.track_ids if len(wanted) else np.zeros(len(kf.track_ids), bool)
        if not ok.any():
            continue
        R, c = poses[k, :3, :3], poses[k, :3, 3]
        ids.append(order[p[ok]])
        dirs.append(kf.bearings[ok] @ R.T)
        centres.append(np.broadcast_to(c, (int(ok.sum()), 3)))
    M = len(wanted)
    points, valid = np.full((M, 3), np.nan), np.zeros(M, bool)
    if not ids:
        return points, valid
    # Each point's rays in their keyframe order (a stable sort), so that a part's sums are the whole's.
    idx = np.concatenate(ids)
    by_point = np.argsort(idx, kind="stable")
    idx, centres, dirs = idx[by_point], np.concatenate(centres)[by_point], np.concatenate(dirs)[by_point]
    views = np.bincount(idx, minlength=M)
    for a in range(0, M, POINTS_AT_ONCE):
        b = min(a + POINTS_AT_ONCE, M)
        lo, hi = np.searchsorted(idx, [a, b])
        tri = triangulate_rays(centres[lo:hi], dirs[lo:hi], idx[lo:hi] - a, b - a, min_parallax_deg=min_parallax_deg,
                               refine_iterations=5)
        points[a:b] = tri.points
        valid[a:b] = tri.valid & (views[a:b] >= min_views) & (tri.max_error_deg <= max_ray_error_deg)
    return points, valid
