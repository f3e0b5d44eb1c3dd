"""Leaving out the observations a predicted video biases most: a track's first keyframes after it began.

A predicted picture (H.264, MPEG-4) is built from the pictures before it, so for a few frames after a track's patch
was cut its later matches stay partly with the picture they were predicted from and lag the wall's motion: on
H.264 at CRF 28, -0.074 px along the motion at a track's second observation, -0.048 at its third, -0.034 at its
fourth, about nothing from its seventh (clean frames: -0.02 px throughout). The tracking still uses them; the map
does not. Keyframes come in order and a track runs through consecutive keyframes, so a keyframe's rows can be
settled as it is made (the VO beside the tracking gets the same keyframes as the map after it)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipemap.frontend.tracks import Keyframe


class SettlingFilter:
    """Drops, keyframe by keyframe, each track's observations number 1..`keyframes` (0 = where it began)."""

    def __init__(self, keyframes: int):
        self.keyframes = int(keyframes)
        self.left_out = 0
        self._young: dict[int, int] = {}  # tracks of the last keyframe still settling: their observations before it
        self._newest = -1  # track ids are handed out in increasing order: above this, a track begins here

    def __call__(self, kf: Keyframe) -> Keyframe:
        if self.keyframes <= 0 or len(kf.track_ids) == 0:
            return kf
        keep = np.ones(len(kf.track_ids), bool)
        young, still = self._young, {}
        for row, tid in enumerate(kf.track_ids.tolist()):
            if tid > self._newest:  # begins here
                still[tid] = 0
            elif tid in young:  # a track runs through consecutive keyframes: one not here has ended
                keep[row] = False
                if young[tid] + 1 < self.keyframes:
                    still[tid] = young[tid] + 1
        self._young = still
        self._newest = max(self._newest, int(kf.track_ids.max()))
        dropped = int((~keep).sum())
        if not dropped:
            return kf
        self.left_out += dropped
        return replace(kf, keypoints=kf.keypoints[keep], bearings=kf.bearings[keep], track_ids=kf.track_ids[keep],
                       inliers=kf.inliers[keep], guided=kf.guided[keep])
