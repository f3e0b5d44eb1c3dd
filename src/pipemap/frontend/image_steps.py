"""The map's keyframe steps against the steps the images' own motion shows: a scale check from outside the map.

A section's free radius (network_checks) triangulates its tracks from its final poses: when the tracks
themselves lag the wall (features stuck on codec flecks in the dark far end of the pipe, which hardly move),
poses and points shrink together, the points still lie on the wall and the free radius stays right. The
flow of a straight pipe's wall needs no map: from a camera on the axis a wall point at angle psi from the
direction of motion lies r cot(psi) along the axis, so a step d turns it from psi_a to psi_b with
d = r (cot psi_a - cot psi_b). Each keyframe's pairs, derotated by its relative rotation, give its step as
the images show it (their median), whatever the map made of it. Off the axis the wall is nearer on
one side and further on the other, and the median over the pairs stays close to the axis's (measured on the
a camera a third of the radius off it makes 0.87 of its step, two thirds 0.69). On 320x240 H.264 CCTV footage whose
windows had shrunk a straight pipe to a fifth of its length, rated good, the map's steps were 0.01-0.5 of
these.
"""

from __future__ import annotations

import numpy as np

# Pairs nearer the direction of motion than this move too little for their flow to say anything.
MIN_ANGLE_DEG = 15.0
# Fewest pairs a keyframe's image step is taken from.
MIN_PAIRS = 8


def image_step(previous, keyframe, radius: float) -> float:
    """The step (m) from keyframe `previous` to `keyframe` that their tracked features' image motion shows in a
    straight pipe of `radius`, or nan (no relative pose, too few pairs)."""
    if not keyframe.pose_valid:
        return float("nan")
    tids = keyframe.track_ids[keyframe.inliers]
    _, i, j = np.intersect1d(previous.track_ids, tids, assume_unique=True, return_indices=True)
    if len(i) < MIN_PAIRS:
        return float("nan")
    R = np.asarray(keyframe.R, float)
    a = np.asarray(previous.bearings, float)[i]
    b = np.asarray(keyframe.bearings, float)[keyframe.inliers][j] @ R  # in the previous camera's frame
    motion = -R.T @ np.asarray(keyframe.t, float)  # the camera's displacement, previous frame
    if not np.linalg.norm(motion) > 0:
        return float("nan")
    motion /= np.linalg.norm(motion)
    cos_a, cos_b = a @ motion, b @ motion
    sin_a, sin_b = np.sqrt(np.maximum(1.0 - cos_a ** 2, 0.0)), np.sqrt(np.maximum(1.0 - cos_b ** 2, 0.0))
    use = np.minimum(sin_a, sin_b) >= np.sin(np.radians(MIN_ANGLE_DEG))
    if use.sum() < MIN_PAIRS:
        return float("nan")
    # on the axis a wall point lies r cot(psi) along it from the camera, before and after the step
    return float(radius * np.median(cos_a[use] / sin_a[use] - cos_b[use] / sin_b[use]))


def step_disagreement(keyframes, poses: np.ndarray, first: int, last: int, radius: float,
                      stretch: int) -> float | None:
    """How far the map's keyframe steps in keyframes first..last (poses (N, 4, 4) T_wc) are from those the image
    motion shows: the largest, over stretches of `stretch` keyframes, of the factor (>= 1) between the median of
    their ratios and 1. None when no stretch has enough keyframes with both."""
    ratios = np.full(last - first + 1, np.nan)
    for k in range(max(first, 1), last + 1):
        seen = image_step(keyframes[k - 1], keyframes[k], radius)
        made = float(np.linalg.norm(poses[k, :3, 3] - poses[k - 1, :3, 3]))
        if np.isfinite(seen) and seen > 0 and made > 0:
            ratios[k - first] = made / seen
    worst = None
    size = min(stretch, len(ratios))
    for lo in range(0, max(1, len(ratios) - size + 1)):
        part = ratios[lo:lo + size]
        part = part[np.isfinite(part)]
        if len(part) < max(3, size // 2):
            continue
        factor = float(np.exp(abs(np.log(np.median(part)))))
        worst = factor if worst is None else max(worst, factor)
    return worst


__all__ = ["image_step", "step_disagreement"]
