"""Keypoints of the 2010 report's sparse VO (section 5.1): region Harris with Gaussian derivative
and integration scales, the sub-pixel quadratic refinement of eqs. 32-34, upright SIFT
descriptors at those keypoints, and ambiguity-ratio matching with a mutual check.

The fisheye front end's region Harris (pipemap.frontend.harris) uses OpenCV's box-window
cornerHarris and a per-axis parabola; the report asks for Gaussian windows (sigma_W, sigma_D)
and a joint 2-D quadratic fit, so the response is computed here. The cornerness is the usual
det(A) - k trace(A)^2 (eq. 29 prints trace(A) unsquared, which is not scale-consistent).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipemap.config import SparseSettings

_SIFT_SIZE_PX = 4.0  # keypoint diameter handed to SIFT: a descriptor window of 4 x 4 cells of 6 px


@dataclass(frozen=True)
class Keypoints:
    """Sub-pixel positions (N, 2) as (u, v), Harris scores (N,) and SIFT descriptors (N, 128)."""

    uv: np.ndarray
    score: np.ndarray
    descriptors: np.ndarray

    def __len__(self) -> int:
        return len(self.uv)


def harris_response(image: np.ndarray, sigma_d: float, sigma_w: float, k: float) -> np.ndarray:
    """Cornerness det(A) - k trace(A)^2 of the second-moment matrix A (eqs. 29-31), float32."""
    img = np.ascontiguousarray(image, np.float32)
    radius = int(np.ceil(3 * sigma_d))
    x = np.arange(-radius, radius + 1, dtype=np.float32)
    g = np.exp(-x * x / (2 * sigma_d * sigma_d))
    g /= g.sum()
    dg = -x / (sigma_d * sigma_d) * g
    # Correlation with -dG equals convolution with dG: I_x = I * dG/dx.
    ix = cv2.sepFilter2D(img, cv2.CV_32F, -dg, g, borderType=cv2.BORDER_REFLECT)
    iy = cv2.sepFilter2D(img, cv2.CV_32F, g, -dg, borderType=cv2.BORDER_REFLECT)
    a = cv2.GaussianBlur(ix * ix, (0, 0), sigma_w, borderType=cv2.BORDER_REFLECT)
    b = cv2.GaussianBlur(ix * iy, (0, 0), sigma_w, borderType=cv2.BORDER_REFLECT)
    c = cv2.GaussianBlur(iy * iy, (0, 0), sigma_w, borderType=cv2.BORDER_REFLECT)
    tr = a + c
    return a * c - b * b - np.float32(k) * tr * tr


def quadratic_refine(response: np.ndarray, us: np.ndarray, vs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 32-34: the extremum of the 2-D quadratic Taylor expansion of the response at integer
    peaks (us, vs): dx = -H^-1 g with central differences. Returns offsets (N, 2) and whether
    each stayed within half a pixel (otherwise the offset is clipped to +-0.5)."""
    R = response
    c = R[vs, us].astype(float)
    l, r = R[vs, us - 1], R[vs, us + 1]
    t, b = R[vs - 1, us], R[vs + 1, us]
    gx, gy = 0.5 * (r - l), 0.5 * (b - t)
    hxx, hyy = r - 2 * c + l, b - 2 * c + t
    hxy = 0.25 * (R[vs + 1, us + 1] - R[vs + 1, us - 1] - R[vs - 1, us + 1] + R[vs - 1, us - 1])
    det = hxx * hyy - hxy * hxy
    ok = (det > 0) & (hxx < 0)  # a maximum: negative definite Hessian
    safe = np.where(ok, det, 1.0)
    dx = np.where(ok, -(hyy * gx - hxy * gy) / safe, 0.0)
    dy = np.where(ok, -(hxx * gy - hxy * gx) / safe, 0.0)
    d = np.stack([dx, dy], axis=-1)
    inside = ok & np.all(np.abs(d) <= 0.5, axis=1)
    return np.clip(d, -0.5, 0.5), inside


def region_corners(response: np.ndarray, grid: tuple[int, int], per_cell: int, nms_px: int,
                   margin: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer peaks (us, vs) of the response: local maxima in an nms_px window, the `per_cell`
    strongest of each cell of a rows x cols grid, at least `margin` pixels from the border."""
    h, w = response.shape
    local_max = cv2.dilate(response, cv2.getStructuringElement(cv2.MORPH_RECT, (nms_px, nms_px)))
    peak = (response >= local_max) & (response > 0)
    m = max(1, margin)
    peak[:m, :] = peak[-m:, :] = False
    peak[:, :m] = peak[:, -m:] = False
    vs, us = np.nonzero(peak)
    if vs.size == 0:
        return us, vs
    score = response[vs, us]
    rows, cols = grid
    cell = (vs * rows // h) * cols + (us * cols // w)
    order = np.lexsort((-score, cell))
    cell_sorted = cell[order]
    rank = np.arange(order.size) - np.searchsorted(cell_sorted, cell_sorted, side="left")
    keep = order[rank < per_cell]
    return us[keep], vs[keep]


def to_uint8(image: np.ndarray) -> np.ndarray:
    """A gain-corrected float image (arbitrary range, report section 3.2) scaled into 0..255 for SIFT."""
    img = np.asarray(image, np.float32)
    hi = float(np.percentile(img[::4, ::4], 99.9))  # a subsample is enough for the bright end
    scale = 255.0 / hi if hi > 0 else 1.0
    return np.clip(img * np.float32(scale), 0, 255).astype(np.uint8)


_SIFT = None


def _sift():
    global _SIFT
    if _SIFT is None:
        _SIFT = cv2.SIFT_create()
    return _SIFT


def flatten_light(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """The image divided by its own Gaussian blur: the light's fall-off across the image removed, the texture
    kept. The robot's LEDs move with the camera, so a corner crossing the image sees the slope of the light
    across it change; that slope shifts its Harris peak, always against the motion (about 0.02 px per keyframe
    on the wall-camera renders without a gain mask, a scale error of 0.1-0.2 % along a track). A gain mask
    removes the same fall-off where one was taken; this needs none."""
    img = np.asarray(image, np.float32)
    blur = cv2.GaussianBlur(img, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
    mean = np.float32(max(float(img.mean()), 1e-6))
    return img / np.maximum(blur, 0.01 * mean) * mean  # unlit corners stay finite; grey levels keep their range


def detect(image: np.ndarray, sparse: SparseSettings, flatten: bool = False) -> Keypoints:
    """Region Harris keypoints of one gain-corrected grey image with their SIFT descriptors (with `flatten`, on
    the image with its light flattened when sparse.light_sigma_px is set: for images no gain mask corrected)."""
    if flatten and sparse.light_sigma_px is not None:
        image = flatten_light(image, sparse.light_sigma_px)
    response = harris_response(image, sparse.sigma_d, sparse.sigma_w, sparse.harris_k)
    margin = int(np.ceil(3 * sparse.sigma_d)) + 1
    us, vs = region_corners(response, tuple(sparse.grid), sparse.corners_per_cell, sparse.nms_px, margin)
    if us.size == 0:
        return Keypoints(np.zeros((0, 2)), np.zeros(0), np.zeros((0, 128), np.float32))
    offset, _ = quadratic_refine(response, us, vs)
    uv = np.stack([us, vs], axis=-1) + offset
    kps = [cv2.KeyPoint(float(u), float(v), _SIFT_SIZE_PX, 0.0, 0.0, 0, i) for i, (u, v) in enumerate(uv)]
    kps, desc = _sift().compute(to_uint8(image), kps)
    if desc is None or len(kps) == 0:
        return Keypoints(np.zeros((0, 2)), np.zeros(0), np.zeros((0, 128), np.float32))
    ids = np.array([k.class_id for k in kps], int)  # compute() may drop keypoints: keep the survivors' order
    return Keypoints(uv[ids], response[vs[ids], us[ids]].astype(float), desc.astype(np.float32))


def match(a: Keypoints, b: Keypoints, ratio: float) -> np.ndarray:
    """Index pairs (M, 2) into a and b: nearest neighbours in descriptor space whose distance is
    below `ratio` times the second nearest (Lowe's ambiguity ratio) and that are each other's
    nearest neighbour (mutual check)."""
    if len(a) < 2 or len(b) < 2:
        return np.zeros((0, 2), int)
    da, db = a.descriptors, b.descriptors
    # |x - y|^2 = |x|^2 + |y|^2 - 2 x.y : one BLAS product for the whole table (|x|^2 is constant per row)
    d2 = (db * db).sum(1)[None, :] - 2.0 * (da @ db.T)
    rows = np.arange(len(a))
    best = np.argmin(d2, axis=1)
    mutual = np.argmin(d2, axis=0)[best] == rows
    d_best = d2[rows, best].copy()
    d2[rows, best] = np.inf
    d_second = d2.min(axis=1)
    norm_a = (da * da).sum(1)
    d_best = np.maximum(d_best + norm_a, 0.0)
    d_second = np.maximum(d_second + norm_a, 0.0)
    keep = mutual & (d_best < (ratio * ratio) * d_second)
    return np.stack([rows[keep], best[keep]], axis=-1)
