"""What the front end hands the back end: keyframes whose features carry track ids."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Keyframe:
    """One keyframe's features and its relative pose to the previous keyframe.

    `R`, `t` map points from the previous keyframe's camera frame into this one's:
    X_this = R @ X_prev + t with |t| = 1 (monocular: the scale is unknown). The first keyframe,
    and one that starts again after tracking was lost (`pose_valid` False), has R = I and
    t = 0 and no tracked features.
    """

    number: int  # 0, 1, 2, ... in order
    index: int  # image index in the dataset
    timestamp: float
    keypoints: np.ndarray  # (N, 2) float32 pixels (u, v)
    bearings: np.ndarray  # (N, 3) float32 unit bearings from the dataset's camera model
    track_ids: np.ndarray  # (N,) int32 (int64 past 2**31 tracks), unique within the keyframe
    inliers: np.ndarray  # (N,) bool: continues a track of the previous keyframe, consistent with R, t
    guided: np.ndarray  # (N,) bool: found by epipolar-guided ZNCC rather than by descriptor matching (descriptors)
    R: np.ndarray  # (3, 3)
    t: np.ndarray  # (3,)
    pose_valid: bool

    def __post_init__(self):
        # Held as float32: 1e-4 px and 1e-7 rad, far below the tracking's noise, and a long run's keyframes are
        # most of its memory (float64 had been 380 MB of a 25,000-frame run's 1.7 GB).
        object.__setattr__(self, "keypoints", np.asarray(self.keypoints, np.float32))
        object.__setattr__(self, "bearings", np.asarray(self.bearings, np.float32))
        # Track ids as int32 while they fit (2.1e9 tracks; a 25,000-frame run makes about 3e6): 37 MB less there.
        ids = np.asarray(self.track_ids)
        if ids.dtype != np.int32 and (ids.size == 0 or ids.max() <= np.iinfo(np.int32).max):
            object.__setattr__(self, "track_ids", ids.astype(np.int32))

    def __len__(self) -> int:
        return len(self.keypoints)

    @property
    def tracked(self) -> int:
        return int(self.inliers.sum())


class TrackIds:
    """Hands out fresh track ids: 0, 1, 2, ..."""

    def __init__(self) -> None:
        self._next = 0

    def new(self, count: int) -> np.ndarray:
        ids = np.arange(self._next, self._next + count, dtype=np.int64)
        self._next += count
        return ids


def track_lengths(keyframes: list[Keyframe]) -> dict[int, int]:
    """Number of keyframes each track id appears in."""
    if not keyframes:
        return {}
    ids, counts = np.unique(np.concatenate([k.track_ids for k in keyframes]), return_counts=True)
    return dict(zip(ids.tolist(), counts.tolist()))
