"""Where the pipe bends: keyframes around which the camera's viewing direction turns.

The image classification sees a tee or a tight elbow by the dark far end of the pipe leaving the
image centre; a long sweeping bend (ten diameters and more) turns the view so slowly that every
frame still looks straight, and a straight section's bundle adjustment, whose wall is one cylinder
bending by millimetres, cannot follow it. Bending is plain in the keyframes' relative rotations,
which need no scale: a crawler in a straight pipe keeps its viewing direction to within its wobble
(a degree or so), while in a bend the direction turns with the pipe. Keyframes are spaced by image
flow, i.e. by a roughly fixed fraction of the pipe radius of travel, so a window of keyframes spans
about the same length of pipe whatever the camera. A window turns when the optical axes of its first
and last keyframes differ by more than the threshold (roll about the axis, which does not bend the
path, does not count); every keyframe of a turning window is in the bend's junction section, so the
straight sections either side keep clear of the bend's wall. Only bends the images missed are looked
for: windows that reach within a window of a classified junction are left to the classification (a
tee's turn runs on a little past the frames classified, and taking that tail from the straight sections
either side shortened them on a small loop enough to cost the appearance map its 2 mm).
"""

from __future__ import annotations

import numpy as np

from pipemap.frontend.tracks import Keyframe


def viewing_directions(keyframes: list[Keyframe]) -> tuple[np.ndarray, np.ndarray]:
    """(optical axes (N, 3) in the frame of each keyframe's chain start, chain number (N,)): relative poses
    chained from each keyframe that starts again after tracking was lost."""
    z = np.zeros((len(keyframes), 3))
    chain = np.zeros(len(keyframes), np.int64)
    R_wc, c = np.eye(3), -1
    for k, kf in enumerate(keyframes):
        if k == 0 or not kf.pose_valid:
            R_wc, c = np.eye(3), c + 1
        else:
            R_wc = R_wc @ np.asarray(kf.R, float).T  # X_this = R X_prev: camera k -> camera k-1 is R^T
        z[k], chain[k] = R_wc[:, 2], c
    return z, chain


def turning_keyframes(keyframes: list[Keyframe], window: int, threshold_deg: float,
                      classified: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: keyframes of any window of `window` keyframes over which the view turns by more than
    `threshold_deg`, among the windows that come no nearer than a window to a keyframe the images already
    classified as a junction (`classified`, (N,) bool): a tee or tight elbow turns the view as it should,
    and widening its section by its turn's tail would swallow the straight pipe between junctions."""
    z, chain = viewing_directions(keyframes)
    return turning_from_directions(z, chain, window, threshold_deg, classified)


# Steps a window's turn is measured without (_turn_without_largest_steps).
LARGEST_STEPS_LEFT_OUT = 2


def _turn_without_largest_steps(z: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) deg: how far the viewing direction turns from keyframe a to b (arrays of equal length) over all but
    its LARGEST_STEPS_LEFT_OUT largest steps from keyframe to keyframe. A bend turns the view a little at every
    keyframe; a wrong relative pose turns it all at once, and the chained directions keep that step for good: on
    320x240 H.264 CCTV footage of a straight pipe two such steps of 2-3 deg turned a window 5-8 deg and made a
    phantom bend two metres long, whose keyframes then had no cylinder to hold their scale."""
    steps = np.diff(z, axis=0)
    if not len(steps):
        return np.zeros(len(a))
    size = np.linalg.norm(steps, axis=1)
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    out = np.empty(len(a))
    for i, (lo, hi) in enumerate(zip(a, b)):
        part = size[lo:hi]
        drop = np.argsort(part)[len(part) - min(LARGEST_STEPS_LEFT_OUT, len(part)):] + lo
        out[i] = np.linalg.norm(cum[hi] - cum[lo] - steps[drop].sum(axis=0))
    return np.degrees(2.0 * np.arcsin(np.clip(out / 2.0, 0.0, 1.0)))


def turning_from_directions(z: np.ndarray, chain: np.ndarray, window: int, threshold_deg: float,
                            classified: np.ndarray | None = None) -> np.ndarray:
    """turning_keyframes of the keyframes' viewing directions and chain numbers (viewing_directions). A window
    turns when its first and last directions differ by more than `threshold_deg` and by more than half of it
    without its two largest steps (_turn_without_largest_steps)."""
    n = len(z)
    out = np.zeros(n, bool)
    if n == 0 or window < 2:
        return out
    half = window // 2
    k = np.arange(n)
    a, b = np.clip(k - half, 0, n - 1), np.clip(k + half, 0, n - 1)
    same = (chain[a] == chain[b]) & (b - a == 2 * half)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", z[a], z[b]), -1.0, 1.0)))
    turning = same & (angle > threshold_deg)
    turns = np.flatnonzero(turning)
    turning[turns] = _turn_without_largest_steps(z, a[turns], b[turns]) > threshold_deg / 2
    if classified is not None:  # and the turn's own tail a window either side of a classified junction
        c = np.concatenate([[0], np.cumsum(np.asarray(classified, bool))])
        near = c[np.clip(k + window + 1, 0, n)] - c[np.clip(k - window, 0, n)] > 0
        seen = np.concatenate([[0], np.cumsum(near)])
        turning &= seen[b + 1] - seen[a] == 0
    for i in np.flatnonzero(turning):
        out[max(0, i - half):i + half + 1] = True
    return out


__all__ = ["viewing_directions", "turning_keyframes", "turning_from_directions"]
