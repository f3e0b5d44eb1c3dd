"""Pixels that do not move with the wall: burned-in text, logos, a dirty lens, the robot's own parts.

The wall's texture moves through the image as the robot drives; an overlay stays where it is. Over
frames spread along the run, the mean of the lighting-flattened images (harris.flatten_lighting:
the LEDs' fall-off, which also stays put, is removed first) keeps the edges of whatever is static
and blurs the moving texture away. A pixel is static where the gradient of that mean is nearly as
strong as the mean of the frames' own gradients (their ratio is 1 for a static edge and about
1/sqrt(n) for moving texture) and the edge is strong. Text whose characters change (a distance
counter, a clock) keeps its outline and the characters that change least; closing over the text
height joins them into one region. The mask is grown by the front end's largest template, so no
feature's patch reaches into the overlay.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import cv2
import numpy as np

from pipemap.frontend.harris import flatten_lighting


@dataclass(frozen=True)
class StaticMask:
    usable: np.ndarray  # (H, W) bool: pixels that move with the wall (features, matching, maps)
    static: np.ndarray  # (H, W) bool: the static structure found, before growing
    frames: int  # frames it was found from
    regions: list[tuple[int, int, int, int]]  # bounding boxes (x, y, w, h) of the static regions

    @property
    def masked_fraction(self) -> float:
        return float(1.0 - self.usable.mean())

    def to_dict(self) -> dict:
        return {"frames_used": self.frames, "masked_fraction": round(self.masked_fraction, 5),
                "regions": [list(r) for r in self.regions]}


def _gradient(img: np.ndarray) -> np.ndarray:
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
    return np.sqrt(gx * gx + gy * gy)


def find_static_mask(images: Iterable[np.ndarray], inside: np.ndarray, lighting_sigma_px: float,
                     min_ratio: float = 0.9, min_edge: float = 8.0, join_px: int = 9, grow_px: int = 8,
                     min_frames: int = 8) -> StaticMask | None:
    """The static overlay of `images` (grey frames spread along the run) within `inside` (the
    camera's image). None when fewer than `min_frames` frames were given (nothing can be told)."""
    total = None
    grad_sum = None
    n = 0
    for img in images:
        flat, _ = flatten_lighting(np.asarray(img, np.float32), lighting_sigma_px)
        g = _gradient(flat)
        total = flat.astype(np.float64) if total is None else total + flat
        grad_sum = g.astype(np.float64) if grad_sum is None else grad_sum + g
        n += 1
    if n < min_frames:
        return None
    mean_grad = (grad_sum / n).astype(np.float32)
    grad_of_mean = _gradient((total / n).astype(np.float32))
    ratio = grad_of_mean / np.maximum(mean_grad, 1e-6)
    static = (ratio > min_ratio) & (grad_of_mean > min_edge) & (inside > 0)
    # the image circle's own rim is static too; it is outside the camera's image already
    static &= cv2.erode(inside.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    joined = static.astype(np.uint8)
    if join_px > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * join_px + 1, 2 * join_px + 1))
        joined = cv2.morphologyEx(joined, cv2.MORPH_CLOSE, k)
    # isolated specks are noise of the mean, not an overlay
    count, labels, stats, _ = cv2.connectedComponentsWithStats(joined, connectivity=8)
    keep = np.zeros(count, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= max(4, (join_px // 2) ** 2)
    joined = keep[labels].astype(np.uint8)
    regions = [tuple(int(v) for v in stats[i, :4]) for i in np.flatnonzero(keep)]
    grown = joined
    if grow_px > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow_px + 1, 2 * grow_px + 1))
        grown = cv2.dilate(joined, k)
    return StaticMask(~grown.astype(bool), static & keep[labels].astype(bool), n, regions)
