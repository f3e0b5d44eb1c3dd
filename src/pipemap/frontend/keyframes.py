"""Keyframe selection (fisheye paper III-A) and the keyframe trajectory of the front end."""

from __future__ import annotations

import numpy as np

from pipemap.frontend.tracks import Keyframe
from pipemap.trajectory import Trajectory


def needs_keyframe(median_flow_px: float, tracked_fraction: float, min_flow_px: float, min_tracked: float) -> bool:
    """A new keyframe once the median sparse flow exceeds its minimum, or too few keyframe features are still tracked.

    `tracked_fraction` is the frame's inlier matches to the keyframe over the most that any
    frame since the keyframe has had (the tracker's measure: Harris corners recur only partly,
    so a fraction of all keyframe features would fall below any threshold at once).
    """
    return median_flow_px > min_flow_px or tracked_fraction < min_tracked


def chain_poses(keyframes: list[Keyframe]) -> Trajectory:
    """T_wc of every keyframe, the first at the origin, each relative step with unit translation.

    Rotations are the front end's estimates; the scale is arbitrary (one unit per keyframe
    step). A step whose pose was lost repeats the previous step's translation direction with
    no rotation, so that the trajectory stays continuous for inspection.
    """
    n = len(keyframes)
    positions = np.zeros((n, 3))
    rotations = np.tile(np.eye(3), (n, 1, 1))
    last_t = np.array([0.0, 0.0, 1.0])
    for k in range(1, n):
        kf = keyframes[k]
        R, t = (kf.R, kf.t) if kf.pose_valid else (np.eye(3), last_t)
        last_t = t
        # X_k = R X_{k-1} + t  =>  camera k in frame k-1: R^T, centre -R^T t.
        positions[k] = positions[k - 1] - rotations[k - 1] @ (R.T @ t)
        rotations[k] = rotations[k - 1] @ R.T
    stamps = np.array([kf.timestamp for kf in keyframes], float)
    return Trajectory(stamps, positions, rotations)
