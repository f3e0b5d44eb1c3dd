"""Repeated frames (a stalled link sends the last picture again) and dropped frames (a gap in time).

Repeated: both smoothed with a Gaussian of 1 px (which takes most of a codec's requantisation
noise and leaves the wall's texture), the picture differs from the last frame that was *not*
repeated by at most `tolerance` grey levels (of 255), as a mean over each 8x8-pixel block, in at
least three quarters of the usable blocks.

Measured on simulated fisheye footage at 160x120 and 320x240: repeats differ by 0.0 (PNG,
MJPEG), at most 0.1 (x264 CRF 28) and 0.4 (CRF 35); frames of a moving camera by 1.5 or more,
except those that barely moved (starting from rest, or CRF 35 smoothing slow motion away),
which this test calls repeated too. A copy that comes back as a keyframe after predicted frames
carries fresh coding noise: up to 1.6 (MPEG-4 qscale 5, or x264 CRF 28 on a noise texture;
3.4 at qscale 12 and 2.1 at CRF 30, poor qualities, where such repeats are missed). Such
frames get twice the tolerance, and the frames predicted from one are compared with it;
slow motion of a smooth wall (2.8 for 1 px per frame at 640x480) stays above it.

Three quarters, because a burned-in clock that keeps running or a logo may change a quarter of
the picture without hiding the stall, while a fisheye's black corners and the dark far end of
the pipe, unchanged as the camera moves, stay below half of it. Comparing with the last kept
frame, not the previous one, means a slow drift is not skipped forever: a frame is kept once it
has moved enough to matter. So "repeated" means "adds nothing visible": a stalled link, or a
camera standing still with nothing changing; skipping either loses nothing.

Dropped: the time between two neighbouring frames is more than 1.5 frame periods; the gap holds
round(gap / period) - 1 missing frames. The period is 1 / fps from dataset.yaml unless the
recording's own median spacing disagrees with it by more than 25 %, which means the yaml is
wrong and counting against it would call every frame a drop."""

from __future__ import annotations

import cv2
import numpy as np

REPEAT_TOLERANCE = 1.0  # grey levels of 255, block mean of the absolute difference
SMOOTH_PX = 1.0
KEYFRAME_FACTOR = 2.0
BLOCK = 8  # pixels
UNCHANGED_SHARE = 0.75  # of the usable blocks
GAP_FACTOR = 1.5
PERIOD_DISAGREEMENT = 0.25


def _blocks(image: np.ndarray) -> np.ndarray:
    """Mean of each BLOCK x BLOCK tile."""
    h, w = image.shape[:2]
    return cv2.resize(image, (max(w // BLOCK, 1), max(h // BLOCK, 1)), interpolation=cv2.INTER_AREA)


class RepeatDetector:
    """Feed frames in order; `is_repeat(image)` says whether it adds nothing to the last kept one."""

    def __init__(self, mask: np.ndarray | None = None, tolerance: float = REPEAT_TOLERANCE):
        self.tolerance = tolerance
        self.kept: np.ndarray | None = None  # the last kept frame, smoothed
        self.mask = None if mask is None else mask.astype(np.float32)
        if self.mask is not None:
            share = _blocks(self.mask)
            self.usable = share >= 0.5  # a block counts when most of it is usable
            self.share = share[self.usable]

    def change(self, image: np.ndarray) -> float:
        """The grey-level change that UNCHANGED_SHARE of the usable blocks stay within."""
        return self._change(_smooth(image))

    def _change(self, smooth: np.ndarray) -> float:
        if self.kept is None or self.kept.shape != smooth.shape:
            return float("inf")
        diff = cv2.absdiff(smooth, self.kept)
        if self.mask is None:
            return float(np.quantile(_blocks(diff), UNCHANGED_SHARE))
        if not self.usable.any():
            return float("inf")
        # The mean over each block's usable pixels.
        return float(np.quantile(_blocks(diff * self.mask)[self.usable] / self.share, UNCHANGED_SHARE))

    def is_repeat(self, image: np.ndarray, requantised: bool = False) -> bool:
        """`requantised`: a video keyframe after predicted frames (RawFrame.requantised)."""
        smooth = _smooth(image)
        repeat = self._change(smooth) <= self.tolerance * (KEYFRAME_FACTOR if requantised else 1.0)
        if not repeat or requantised:
            # A copy coded afresh is what the frames predicted from it will look like: compare them with it.
            self.kept = smooth
        return repeat


def _smooth(image: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(image.astype(np.float32, copy=False), (0, 0), SMOOTH_PX)


def frame_period(times: np.ndarray, fps: float) -> float:
    """The spacing that drops are counted against: 1 / fps, or the recording's median spacing
    where that disagrees with it by more than PERIOD_DISAGREEMENT."""
    nominal = 1.0 / fps
    gaps = np.diff(np.asarray(times, np.float64))
    gaps = gaps[gaps > 0]
    if not len(gaps):
        return nominal
    median = float(np.median(gaps))
    return median if abs(median - nominal) > PERIOD_DISAGREEMENT * nominal else nominal


def missing_before(times: np.ndarray, period: float) -> np.ndarray:
    """(n,) int: frames missing between each frame and the one before it (0 for the first)."""
    gaps = np.diff(np.asarray(times, np.float64), prepend=times[0] if len(times) else 0.0)
    missing = np.where(gaps > GAP_FACTOR * period, np.rint(gaps / period) - 1, 0)
    return missing.astype(np.int64)
