"""The pose of any frame of a recording from the keyframes' poses.

A keyframe has its own. Between keyframes the position is interpolated in frame index with a modified Akima
spline (the robot speeds up and slows down smoothly: linear interpolation is 5 mm off during the start ramp
of the demo loop, the spline 2 mm). The orientation is not interpolated where the images can be read: a
robot turning into a tee starts its turn between two keyframes, and slerp between them was 1.6-2.0 deg off
there (demo loop). Instead the frame is registered to its nearest keyframe: corners of the keyframe tracked into
the frame (pyramidal Lucas-Kanade, kept where tracking back returns within half a pixel), unprojected to
bearings and passed to the five-point MSAC (frontend.relpose), whose rotation turns the keyframe's orientation
into the frame's (0.10-0.18 deg off there). Frames before the first or after the last keyframe take the
nearest keyframe's pose.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.interpolate import Akima1DInterpolator
from scipy.spatial.transform import Rotation, Slerp

from pipemap.camera import CameraModel
from pipemap.frontend.angular import pixel_angle
from pipemap.frontend.harris import valid_mask
from pipemap.frontend.relpose import estimate_relative_pose

CORNERS = 600  # corners of the keyframe to track: a few hundred pairs fix a rotation to a tenth of a degree
LK_WINDOW = 21
LK_LEVELS = 3
ROUND_TRIP_PX = 0.5  # a track whose way back misses its start by more than this is dropped
MIN_PAIRS = 30
MIN_FLOW_PX = 1.0  # a frame that hardly moved (a repeated one) has no baseline to register over


def interpolated_pose(frames: np.ndarray, poses: np.ndarray, frame: int) -> tuple[np.ndarray, np.ndarray, str]:
    """(R_wc, centre, how) of `frame` from the keyframes' frame indices (K,) and poses T_wc (K, 4, 4)."""
    k = int(np.searchsorted(frames, frame))
    if k < len(frames) and frames[k] == frame:
        return poses[k, :3, :3], poses[k, :3, 3], "keyframe"
    if k == 0 or k == len(frames):
        k = min(k, len(frames) - 1)
        return poses[k, :3, :3], poses[k, :3, 3], "nearest keyframe"
    f0, f1 = frames[k - 1], frames[k]
    R = Slerp([0.0, 1.0], Rotation.from_matrix(poses[k - 1:k + 1, :3, :3]))([(frame - f0) / (f1 - f0)]).as_matrix()[0]
    if len(frames) >= 3:
        C = Akima1DInterpolator(frames, poses[:, :3, 3], method="makima")(frame)
    else:
        a = (frame - f0) / (f1 - f0)
        C = (1 - a) * poses[k - 1, :3, 3] + a * poses[k, :3, 3]
    return R, np.asarray(C, float), "interpolated"


def registered_rotation(camera: CameraModel, key_image: np.ndarray, image: np.ndarray, R_key: np.ndarray,
                        threshold_px: float, seed: int = 0) -> np.ndarray | None:
    """R_wc of a frame registered to a keyframe (grey images, the keyframe's R_wc); None where too few corners
    track or the five-point estimate fails."""
    a, b = (np.clip(im, 0, 255).astype(np.uint8) for im in (key_image, image))
    corners = cv2.goodFeaturesToTrack(a, CORNERS, 0.01, 8, mask=valid_mask(camera, LK_WINDOW // 2).astype(np.uint8))
    if corners is None or len(corners) < MIN_PAIRS:
        return None
    lk = dict(winSize=(LK_WINDOW, LK_WINDOW), maxLevel=LK_LEVELS)
    ahead, ok1, _ = cv2.calcOpticalFlowPyrLK(a, b, corners, None, **lk)
    back, ok2, _ = cv2.calcOpticalFlowPyrLK(b, a, ahead, None, **lk)
    good = (ok1[:, 0] == 1) & (ok2[:, 0] == 1) & (np.linalg.norm(back - corners, axis=2)[:, 0] < ROUND_TRIP_PX)
    bearings_key, valid_key = camera.unproject(corners[good, 0].astype(float))
    bearings, valid = camera.unproject(ahead[good, 0].astype(float))
    both = valid_key & valid
    if both.sum() < MIN_PAIRS or np.median(np.linalg.norm(ahead - corners, axis=2)[good, 0]) < MIN_FLOW_PX:
        return None
    rel = estimate_relative_pose(bearings_key[both], bearings[both], threshold_px * pixel_angle(camera),
                                 rng=np.random.default_rng(seed), min_inliers=MIN_PAIRS)
    if rel is None:
        return None
    return R_key @ rel.R.T  # X_frame = R X_key + t in camera coordinates


__all__ = ["interpolated_pose", "registered_rotation"]
