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

Compressed footage has static edges of its own that are no overlay. Where the pipe is unlit (the dark far end of
a straight pipe, always round the image centre), the codec quantises the little light there into blocks that stay
where they are: on fisheye-straight as MJPEG (quality 8) they made a 94 x 86 px region at the centre that,
masked, hid the far end from the classification, and every frame of the straight pipe was a junction (forward /
reverse -1.8 / +8.9 %). A region whose brightest static pixels (99th percentile of the frames' mean) stay below
the classification's dark level (`dark_share` of the grey range) is unlit pipe, no overlay: kept from the features
like the rings below but left to the classification and the maps. Text meant to be read is bright.
And where the light falls off
towards the rim, the codec quantises the smooth ramp into steps that stay where they are, rings
round the image centre (tee-pass-loop as MJPEG: a dotted ring that, joined and grown, masked 15 %
of the image, the rim where a tee's side opening shows, and the tee passed straight through was
lost). Such a ring is a thin band round the centre (its pixels' distances from it spread by a few
pixels), most of its edges run round the centre and they are weak; burned-in text spreads further
in that distance, has edges every way, or strong ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import cv2
import numpy as np

from pipemap.frontend.harris import flatten_lighting


@dataclass(frozen=True)
class StaticMask:
    usable: np.ndarray  # (H, W) bool: pixels that move with the wall (features, matching)
    static: np.ndarray  # (H, W) bool: the static structure found, before growing
    frames: int  # frames it was found from
    regions: list[tuple[int, int, int, int]]  # bounding boxes (x, y, w, h) of the static regions
    view: np.ndarray  # (H, W) bool: `usable`, the light's rings and unlit regions: pipe (classification, maps)
    rings: int  # regions that are rings of the light's fall-off
    unlit: int = 0  # regions that are unlit pipe whose codec blocks stay put

    @property
    def masked_fraction(self) -> float:
        return float(1.0 - self.usable.mean())

    def to_dict(self) -> dict:
        return {"frames_used": self.frames, "masked_fraction": round(self.masked_fraction, 5),
                "regions": [list(r) for r in self.regions], "light_rings": self.rings, "unlit_regions": self.unlit}


def _gradient(img: np.ndarray) -> np.ndarray:
    return np.hypot(*_sobel(img))


def _sobel(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)


def _light_rings(gx: np.ndarray, gy: np.ndarray, labels: np.ndarray, count: int, static: np.ndarray,
                 centre: tuple[float, float], width_px: float, share: float, within_deg: float,
                 max_edge: float) -> np.ndarray:
    """(count,) bool: the labelled regions that are rings of the light's fall-off round `centre` (module
    docstring): their static pixels' distances from it spread by less than `width_px` (standard deviation),
    at least `share` of their edges run round it (gradient within `within_deg` of the radial direction) and
    their mean edge is below `max_edge`."""
    ys, xs = np.nonzero(static)
    rx, ry = xs - centre[0], ys - centre[1]
    r = np.hypot(rx, ry)
    g = np.hypot(gx[ys, xs], gy[ys, xs])
    cos = np.abs(gx[ys, xs] * rx + gy[ys, xs] * ry) / np.maximum(g * r, 1e-9)
    lab = labels[ys, xs]
    n = np.maximum(np.bincount(lab, minlength=count).astype(float), 1.0)
    mean_r = np.bincount(lab, weights=r, minlength=count) / n
    spread = np.sqrt(np.maximum(np.bincount(lab, weights=r * r, minlength=count) / n - mean_r ** 2, 0.0))
    radial = np.bincount(lab, weights=cos >= np.cos(np.radians(within_deg)), minlength=count) / n
    edge = np.bincount(lab, weights=g, minlength=count) / n
    return (spread < width_px) & (radial >= share) & (edge < max_edge)


def find_static_mask(images: Iterable[np.ndarray], inside: np.ndarray, lighting_sigma_px: float,
                     min_ratio: float = 0.9, min_edge: float = 8.0, join_px: int = 9, grow_px: int = 8,
                     min_frames: int = 8, centre: tuple[float, float] | None = None,
                     ring_width_px: float = 4.0, ring_share: float = 0.5, ring_within_deg: float = 20.0,
                     ring_max_edge: float = 40.0, dark_share: float | None = 0.25) -> StaticMask | None:
    """The static overlay of `images` (grey frames spread along the run) within `inside` (the
    camera's image). None when fewer than `min_frames` frames were given (nothing can be told).
    `centre`: where the light's rings are centred (the principal point; None: the middle of `inside`);
    `ring_*`: what makes a region such a ring and no overlay (_light_rings; edges in flattened units);
    `dark_share`: a region whose brightest pixels stay below this share of the grey range is unlit (None: none is)."""
    total = None
    grad_sum = None
    grey = None
    n = 0
    for img in images:
        img = np.asarray(img, np.float32)
        grey = img.astype(np.float64) if grey is None else grey + img
        flat, _ = flatten_lighting(img, lighting_sigma_px)
        g = _gradient(flat)
        total = flat.astype(np.float64) if total is None else total + flat
        grad_sum = g.astype(np.float64) if grad_sum is None else grad_sum + g
        n += 1
    if n < min_frames:
        return None
    mean_grad = (grad_sum / n).astype(np.float32)
    gx, gy = _sobel((total / n).astype(np.float32))
    grad_of_mean = np.hypot(gx, gy)
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
    if centre is None:
        ys, xs = np.nonzero(inside)
        centre = (float(xs.mean()), float(ys.mean())) if len(xs) else (inside.shape[1] / 2, inside.shape[0] / 2)
    ring = keep & _light_rings(gx, gy, labels, count, static, centre, ring_width_px, ring_share, ring_within_deg,
                               ring_max_edge)
    unlit = keep & ~ring & _unlit(grey / n, labels, count, static, inside > 0, dark_share)
    overlay = keep & ~ring & ~unlit
    regions = [tuple(int(v) for v in stats[i, :4]) for i in np.flatnonzero(overlay)]

    def grow(regions_kept: np.ndarray) -> np.ndarray:
        joined = regions_kept[labels].astype(np.uint8)
        if grow_px > 0:
            disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow_px + 1, 2 * grow_px + 1))
            joined = cv2.dilate(joined, disc)
        return joined.astype(bool)

    # the rings stay out of the features' pixels: their steps stay put and would hold features back
    return StaticMask(~grow(keep), static & keep[labels], n, regions, view=~grow(overlay), rings=int(ring.sum()),
                      unlit=int(unlit.sum()))


def _unlit(mean: np.ndarray, labels: np.ndarray, count: int, static: np.ndarray, inside: np.ndarray,
           dark_share: float | None) -> np.ndarray:
    """(count,) bool: the labelled regions whose static pixels' 99th percentile of the mean grey image `mean` lies
    below the dark level, lo + dark_share (hi - lo) with lo, hi its 1st and 99th percentiles inside the image."""
    out = np.zeros(count, bool)
    if dark_share is None or not inside.any():
        return out
    lo, hi = np.percentile(mean[inside], [1.0, 99.0])
    level = lo + dark_share * (hi - lo)
    ys, xs = np.nonzero(static)
    lab, value = labels[ys, xs], mean[ys, xs]
    for i in np.unique(lab):
        out[i] = np.percentile(value[lab == i], 99.0) < level
    out[0] = False  # the background label
    return out
