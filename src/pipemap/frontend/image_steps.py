"""The map's keyframe steps against the steps the images' own motion shows: a scale check from outside the map.

A section's free radius (network_checks) triangulates its tracks from its final poses: when the tracks
themselves lag the wall (features stuck on codec flecks in the dark far end of the pipe, which hardly move),
poses and points shrink together, the points still lie on the wall and the free radius stays right. The
flow of a straight pipe's wall needs no map: from a camera on the axis a wall point at angle psi from the
direction of motion lies r cot(psi) along the axis, so a step d turns it from psi_a to psi_b with
d = r (cot psi_a - cot psi_b). Each keyframe's pairs, derotated by its relative rotation, give its step as
the images show it (their median), whatever the map made of it. Off the axis the wall is nearer on
one side and further on the other (a camera a third of the radius off it reads 0.87 of its step, two thirds
0.69); where the map has fitted the section's wall, each pair's point is put where its first ray meets it and
the step is exact there too (the wall's radius is the given one, so the camera's place in the pipe is metric
whatever the map's steps). On 320x240 H.264 CCTV footage whose windows had shrunk a straight pipe to a fifth
of its length, rated good, the map's steps were 0.01-0.5 of these.
"""

from __future__ import annotations

import numpy as np

# Pairs nearer the direction of motion than this move too little for their flow to say anything.
MIN_ANGLE_DEG = 15.0
# Fewest pairs a keyframe's image step is taken from.
MIN_PAIRS = 8


def _pairs(previous, keyframe):
    """The tracks the keyframe continues from `previous`: (their bearings there, their bearings in the keyframe
    turned into the previous camera's frame, the camera's unit displacement in that frame), or None."""
    if not keyframe.pose_valid:
        return None
    tids = keyframe.track_ids[keyframe.inliers]
    _, i, j = np.intersect1d(previous.track_ids, tids, assume_unique=True, return_indices=True)
    if len(i) < MIN_PAIRS:
        return None
    R = np.asarray(keyframe.R, float)
    motion = -R.T @ np.asarray(keyframe.t, float)
    if not np.linalg.norm(motion) > 0:
        return None
    a = np.asarray(previous.bearings, float)[i]
    b = np.asarray(keyframe.bearings, float)[keyframe.inliers][j] @ R
    return a, b, motion / np.linalg.norm(motion)


def image_step(previous, keyframe, radius: float, wall=None) -> float:
    """The step (m) from keyframe `previous` to `keyframe` that their tracked features' image motion shows in a
    straight pipe of `radius`, or nan (no relative pose, too few pairs). `wall`: (the previous camera's R_wc and
    centre, the pipe's Cylinder) where the map knows where the camera sits in the pipe: each pair's wall point is
    then where its first ray meets that wall, and the step is the one along the motion that turns the point's
    ray into its second (least squares), exact off the axis too; without it the camera is taken on the axis."""
    pairs = _pairs(previous, keyframe)
    if pairs is None:
        return float("nan")
    a, b, motion = pairs
    cos_a, cos_b = a @ motion, b @ motion
    sin_a, sin_b = np.sqrt(np.maximum(1.0 - cos_a ** 2, 0.0)), np.sqrt(np.maximum(1.0 - cos_b ** 2, 0.0))
    use = np.minimum(sin_a, sin_b) >= np.sin(np.radians(MIN_ANGLE_DEG))
    if use.sum() < MIN_PAIRS:
        return float("nan")
    if wall is None:
        # on the axis a wall point lies r cot(psi) along it from the camera, before and after the step
        return float(radius * np.median(cos_a[use] / sin_a[use] - cos_b[use] / sin_b[use]))
    (R_wc, centre), cylinder = wall
    a_w, b_w, m_w = a[use] @ R_wc.T, b[use] @ R_wc.T, R_wc @ motion
    u = np.asarray(cylinder.direction, float) / np.linalg.norm(cylinder.direction)
    q = np.asarray(centre, float) - np.asarray(cylinder.origin, float)
    q_perp, a_perp = q - (q @ u) * u, a_w - np.outer(a_w @ u, u)
    # |q_perp + lam a_perp| = r: the camera is inside, so the larger root is the wall ahead of the ray
    A = np.einsum("ij,ij->i", a_perp, a_perp)
    B = 2.0 * a_perp @ q_perp
    C = q_perp @ q_perp - cylinder.radius ** 2
    lam = (-B + np.sqrt(np.maximum(B * B - 4 * A * C, 0.0))) / np.maximum(2 * A, 1e-12)
    to_point = lam[:, None] * a_w  # from the previous camera
    mb = np.cross(m_w, b_w)
    d = np.einsum("ij,ij->i", np.cross(to_point, b_w), mb) / np.maximum(np.einsum("ij,ij->i", mb, mb), 1e-12)
    ok = (C < 0) & (A > 1e-9) & np.isfinite(d)
    return float(np.median(d[ok])) if ok.sum() >= MIN_PAIRS else float("nan")


def step_disagreement(keyframes, poses: np.ndarray, first: int, last: int, radius: float,
                      stretch: int, cylinder=None) -> float | None:
    """How far the map's keyframe steps in keyframes first..last (poses (N, 4, 4) T_wc) are from those the image
    motion shows (in the map's straight `cylinder` where given, see image_step): the largest, over stretches of
    `stretch` keyframes, of the factor (>= 1) between the median of their ratios and 1. None when no stretch has
    enough keyframes with both."""
    ratios = np.full(last - first + 1, np.nan)
    for k in range(max(first, 1), last + 1):
        wall = None if cylinder is None else ((poses[k - 1, :3, :3], poses[k - 1, :3, 3]), cylinder)
        seen = image_step(keyframes[k - 1], keyframes[k], radius, wall)
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
