"""De-interlacing: an interlaced frame holds two fields taken 1/50 or 1/60 s apart, so a moving
camera shows combed edges that look like texture to the feature detector.

`bob` keeps the field shown first and rebuilds the other's lines as the mean of the lines above
and below: one instant per frame at half the vertical detail (one frame out per frame in: a
crawler moves too slowly for field-rate output to help, and the frame count and timestamps stay
the recording's). `blend` filters every column with [1, 2, 1] / 4, which mixes the two fields
into one frame without a vertical shift: full detail where nothing moves, a slight blur where
something does."""

from __future__ import annotations

import cv2
import numpy as np

METHODS = ("none", "bob", "blend")
_BLEND = np.array([[0.25], [0.5], [0.25]], np.float32)


def deinterlace(image: np.ndarray, method: str, top_field_first: bool = True) -> np.ndarray:
    """(H, W) float32 grey -> the same shape, de-interlaced by `method` (one of METHODS)."""
    if method == "none" or image.shape[0] < 3:
        return image
    if method == "blend":
        return cv2.filter2D(image, -1, _BLEND, borderType=cv2.BORDER_REFLECT_101)
    if method != "bob":
        raise ValueError(f"unknown de-interlacing method {method!r}")
    out = image.copy()
    keep = 0 if top_field_first else 1
    rebuild = 1 - keep
    rows = np.arange(rebuild, image.shape[0], 2)
    below = np.where(rows + 1 < image.shape[0], rows + 1, rows - 1)
    above = np.where(rows - 1 >= 0, rows - 1, rows + 1)
    out[rows] = 0.5 * (image[above] + image[below])
    return out
