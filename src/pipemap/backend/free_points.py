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
                max_ray_error_deg: float, min_views: int = 3, refine_iterations: int = 5
                ) -> tuple[np.ndarray, np.ndarray]:
    """(points (M, 3), valid (M,)) for the tracks `track_ids`, from every keyframe that observes them (poses
    (N, 4, 4) T_wc of `keyframes`). A point is valid with at least `min_views` rays, the parallax, and no ray
    farther than `max_ray_error_deg` from it; each point the rays' midpoint refined `refine_iterations` times
    (triangulate_rays).

    Track ids are handed out in time, so POINTS_AT_ONCE consecutive ids are seen by a short run of keyframes:
    each part gathers its rays from those alone (all of a long run's rays at once would take gigabytes), each
    point's rays in keyframe order."""
    wanted = np.asarray(track_ids, np.int64)
    M = len(wanted)
    points, valid = np.full((M, 3), np.nan), np.zeros(M, bool)
    order = np.argsort(wanted, kind="stable")
    ids = wanted[order]
    seen = [k for k, kf in enumerate(keyframes) if len(kf.track_ids)]
    low = np.array([keyframes[k].track_ids.min() for k in seen], np.int64)
    high = np.array([keyframes[k].track_ids.max() for k in seen], np.int64)
    for a in range(0, M, POINTS_AT_ONCE):
        part = ids[a:a + POINTS_AT_ONCE]
        rays = [_rays(keyframes[k], poses[k], part) for k in np.asarray(seen)[(high >= part[0]) & (low <= part[-1])]]
        rays = [r for r in rays if len(r[0])]
        if not rays:
            continue
        idx, centres, dirs = (np.concatenate(x) for x in zip(*rays))
        by_point = np.argsort(idx, kind="stable")
        idx, centres, dirs = idx[by_point], centres[by_point], dirs[by_point]
        tri = triangulate_rays(centres, dirs, idx, len(part), min_parallax_deg=min_parallax_deg,
                              refine_iterations=refine_iterations)
        views = np.bincount(idx, minlength=len(part))
        rows = order[a:a + POINTS_AT_ONCE]
        points[rows] = tri.points
        valid[rows] = tri.valid & (views >= min_views) & (tri.max_error_deg <= max_ray_error_deg)
    return points, valid


def _rays(kf: Keyframe, pose: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position in the sorted `ids`, centre, world direction) of the keyframe's observations of those tracks."""
    p = np.clip(np.searchsorted(ids, kf.track_ids), 0, len(ids) - 1)
    ok = ids[p] == kf.track_ids
    R, c = pose[:3, :3], pose[:3, 3]
    return p[ok], np.broadcast_to(c, (int(ok.sum()), 3)), kf.bearings[ok] @ R.T
