"""Too little to map: a recording whose frames are dark, blank, frozen or too few is refused with one
line that says which, before any result folder is kept.

`FrameStats` is fed every distinct frame the method reads (a 4x reduced copy: a few tenths of a
millisecond), and `require_mappable` judges the run once its frames are read and tracked.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pipemap.config import Settings
from pipemap.errors import PipemapError

_REDUCE = 4  # frames are judged at a quarter of their size: lighting and texture do not need more


class FrameStats:
    """Per frame: the fraction of lit pixels and the texture of the lit part."""

    def __init__(self, dark_level: float, min_lit_fraction: float, min_texture: float):
        self.dark_level, self.min_lit, self.min_texture = dark_level, min_lit_fraction, min_texture
        self.frames = 0
        self.dark = 0
        self.blank = 0

    @classmethod
    def for_settings(cls, settings: Settings) -> "FrameStats":
        q = settings.quality
        return cls(settings.frontend.dark_level, q.min_lit_fraction, q.min_texture)

    def add(self, image: np.ndarray) -> None:
        small = cv2.resize(np.asarray(image, np.float32), None, fx=1 / _REDUCE, fy=1 / _REDUCE,
                           interpolation=cv2.INTER_AREA)
        lit = small > self.dark_level
        self.frames += 1
        if lit.mean() < self.min_lit:
            self.dark += 1
            return
        # texture: what is left once the lighting (a wide blur) is taken away
        detail = small - cv2.GaussianBlur(small, (0, 0), 3.0)
        if float(np.std(detail[lit])) < self.min_texture:
            self.blank += 1


def require_mappable(stats: FrameStats, keyframes: int, frames_total: int, repeated: int, settings: Settings,
                     where: str | Path) -> None:
    """Raise PipemapError when the frames read hold too little to map."""
    q = settings.quality
    n = stats.frames
    if n and stats.dark >= 0.9 * n:
        raise PipemapError(f"{stats.dark} of {n} distinct frames ({frames_total} read) are dark "
                           f"(fewer than {100 * q.min_lit_fraction:.0f} % of their pixels above grey level "
                           f"{settings.frontend.dark_level:g}): were the robot's lights on? nothing was mapped", where)
    if n and stats.dark + stats.blank >= 0.9 * n:
        raise PipemapError(f"{stats.blank} of {n} distinct frames show no wall texture (grey-level detail below "
                           f"{q.min_texture:g}): a covered or defocused lens? nothing was mapped", where)
    if n < q.min_frames:
        stalled = f" ({repeated} repeat the frame before: a frozen picture)" if repeated else ""
        raise PipemapError(f"only {n} distinct frame{'s' if n != 1 else ''} of {frames_total}{stalled}; mapping needs "
                           f"at least quality.min_frames = {q.min_frames}", where)
    if keyframes < q.min_keyframes:
        raise PipemapError(f"the camera's motion could not be followed: {keyframes} keyframe"
                           f"{'s' if keyframes != 1 else ''} in {n} frames (the robot did not move, or its images "
                           "do not match from one to the next); nothing was mapped", where)


__all__ = ["FrameStats", "require_mappable"]
