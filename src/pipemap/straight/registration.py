"""Dense 2-D translation between two frames (2010 report section 4.2).

Convention: `t = (tx, ty)` is the displacement of the image content from `I0` to `I1`, i.e.
`I1(x + t) = I0(x)`. The region compared is a central band of `I0` (`rows`: first and last
row, the rest of the width that the shift leaves inside both images).

- `full_search`: every integer shift within `prior +- search` (Algorithm 1), by SAD, SSD or
  ZNCC (eqs. 13-15), with OpenCV's matchTemplate for SSD/ZNCC and a windowed view for SAD. The
  template is the part of the band that every shift of the range keeps inside `I1`.
- `adaptive_full_search`: the range around the predicted shift doubles while the best match lies
  on its edge or correlates poorly, so no fixed range has to suit every run.
- `lucas_kanade`: hierarchical Gauss-Newton on the SSD (eqs. 21-27, after Bergen et al.) over
  a cv2.pyrDown pyramid, inverse-compositional (template gradients and Hessian fixed per level).
- `hybrid`: full search, then Lucas-Kanade at the finest level only (section 4.2.3).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from pipemap.errors import PipemapError

Metric = Literal["sad", "ssd", "zncc"]
_SAD_CHUNK_BYTES = 32 * 2**20  # at most this much temporary memory per SAD chunk


@dataclass(frozen=True)
class Shift:
    t: np.ndarray  # (2,) content displacement I0 -> I1 in pixels
    score: float  # cost at the optimum (SAD/SSD per pixel, -ZNCC), or LK RMS residual
    iterations: int = 0


def _band(shape, rows, margin_x: int, margin_y: int):
    """Template box (y0, y1, x0, x1) of I0: the row band, shrunk so shifts up to the margins stay inside."""
    h, w = shape
    y0, y1 = (0, h) if rows is None else (int(rows[0]), int(rows[1]))
    y0, y1 = max(y0, margin_y), min(y1, h - margin_y)
    x0, x1 = margin_x, w - margin_x
    if y1 - y0 < 8 or x1 - x0 < 8:
        raise PipemapError(f"a shift of up to {margin_x}x{margin_y} px leaves no template in the {w}x{h} rectified "
                           "image; lower dense.search_px or raise dense.scale", key="dense.search_px")
    return y0, y1, x0, x1


def _search_box(shape, rows, lo, hi):
    """Template box (y0, y1, x0, x1) of I0 (within the row band) that every shift from lo to hi (x, y) keeps inside
    an image of the same shape; None when that leaves less than 8 x 8 pixels."""
    h, w = shape
    y0, y1 = (0, h) if rows is None else (int(rows[0]), int(rows[1]))
    x0, x1 = max(0, -lo[0]), min(w, w - hi[0])
    y0, y1 = max(y0, -lo[1]), min(y1, h - hi[1])
    return None if y1 - y0 < 8 or x1 - x0 < 8 else (y0, y1, x0, x1)


def full_search(I0: np.ndarray, I1: np.ndarray, search=(16, 8), prior=(0, 0), metric: Metric = "zncc",
                rows=None) -> Shift:
    """Integer shift minimising the metric over `prior +- search` (x, y)."""
    I0 = np.asarray(I0, np.float32)
    I1 = np.asarray(I1, np.float32)
    sx, sy = int(search[0]), int(search[1])
    px, py = int(round(prior[0])), int(round(prior[1]))
    box = _search_box(I0.shape, rows, (px - sx, py - sy), (px + sx, py + sy))
    if box is None:
        h, w = I0.shape
        raise PipemapError(f"a shift of {px}+-{sx} x {py}+-{sy} px leaves no template in the {w}x{h} rectified "
                           "image; lower dense.search_px or raise dense.scale", key="dense.search_px")
    y0, y1, x0, x1 = box
    T = I0[y0:y1, x0:x1]
    S = I1[y0 + py - sy:y1 + py + sy, x0 + px - sx:x1 + px + sx]
    if metric == "zncc":
        R = -cv2.matchTemplate(S, T, cv2.TM_CCOEFF_NORMED)
    elif metric == "ssd":
        R = cv2.matchTemplate(S, T, cv2.TM_SQDIFF) / T.size
    elif metric == "sad":
        R = _sad(S, T)
    else:
        raise ValueError(f"unknown metric {metric!r} (expected sad, ssd or zncc)")
    j, i = np.unravel_index(int(np.argmin(R)), R.shape)
    return Shift(np.array([px + i - sx, py + j - sy], float), float(R[j, i]))


def adaptive_full_search(I0: np.ndarray, I1: np.ndarray, search=(16, 8), prior=(0, 0), metric: Metric = "zncc",
                         rows=None, min_zncc: float = 0.5, min_template: float = 1 / 3) -> Shift:
    """`full_search` around the predicted shift `prior`, with the range `search` to start with. The range doubles
    while the best match lies on its edge (the motion may lie beyond it) or its ZNCC is below min_zncc (it may be
    a false match), as far as the template keeps min_template of the band's width and height; a best match still
    on the edge of the widest range becomes the centre of a new search (the prediction was far off)."""
    I0 = np.asarray(I0, np.float32)
    I1 = np.asarray(I1, np.float32)
    h, w = I0.shape
    y0, y1 = (0, h) if rows is None else (int(rows[0]), int(rows[1]))
    need = np.array([min_template * w, min_template * (y1 - y0)])
    start = np.maximum(np.asarray(search, int), (1, 0))
    p, s = np.round(np.asarray(prior, float)).astype(int), start.copy()

    def fits(p, s):
        box = _search_box(I0.shape, rows, p - s, p + s)
        return box is not None and box[3] - box[2] >= need[0] and box[1] - box[0] >= need[1]

    if not fits(p, s):
        p = np.zeros(2, int)  # the prediction leaves too little overlap: start from no motion
        if not fits(p, s):
            return full_search(I0, I1, s, p, metric, rows)  # the clear error, or a small image searched as asked
    best = None
    for _ in range(4):  # recentrings
        while True:
            found = full_search(I0, I1, s, p, metric, rows)
            best = found if best is None or found.score < best.score else best
            edge = ~((np.abs(found.t - p) < s) | (s == 0))
            box = _search_box(I0.shape, rows, p - s, p + s)
            if not edge.any() and zncc_at(I0, I1, found.t, box) >= min_zncc:
                return found
            grown = s.copy()
            for axis in (0, 1):  # the widest range up to twice the present one that keeps the template
                while grown[axis] < 2 * s[axis] and fits(p, grown + np.eye(2, dtype=int)[axis]):
                    grown[axis] += 1
            if np.array_equal(grown, s):
                break
            s = grown
        if not edge.any() or np.array_equal(found.t, p):
            return best
        p, s = found.t.astype(int), start.copy()
        if not fits(p, s):
            return best
    return best


def zncc_at(I0: np.ndarray, I1: np.ndarray, t, box) -> float:
    """ZNCC of I0 over box (y0, y1, x0, x1) with I1 shifted by the integer shift t."""
    y0, y1, x0, x1 = box
    tx, ty = int(round(t[0])), int(round(t[1]))
    A = I0[y0:y1, x0:x1].astype(np.float64)
    B = I1[y0 + ty:y1 + ty, x0 + tx:x1 + tx].astype(np.float64)
    if A.shape != B.shape or A.size == 0:
        return -1.0
    A, B = A - A.mean(), B - B.mean()
    d = np.sqrt(np.sum(A * A) * np.sum(B * B))
    return float(np.sum(A * B) / d) if d > 0 else -1.0


def _sad(S: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Mean absolute difference of T against every placement in S, in chunks of shift rows."""
    view = sliding_window_view(S, T.shape)  # (ny, nx, th, tw), no copy
    ny, nx = view.shape[:2]
    rows_per_chunk = max(1, _SAD_CHUNK_BYTES // (nx * T.size * 4))
    out = np.empty((ny, nx), np.float32)
    for a in range(0, ny, rows_per_chunk):  # a few chunks, each vectorised over shifts and pixels
        b = min(ny, a + rows_per_chunk)
        out[a:b] = np.abs(view[a:b] - T).mean(axis=(2, 3))
    return out


def _pyramid(img: np.ndarray, levels: int) -> list[np.ndarray]:
    pyr = [np.asarray(img, np.float32)]
    for _ in range(levels - 1):
        if min(pyr[-1].shape) < 32:
            break
        pyr.append(cv2.pyrDown(pyr[-1]))
    return pyr


def _keys(f: float) -> np.ndarray:
    """Keys cubic convolution weights (a = -0.5) of the taps at -1, 0, 1, 2 for a fraction f in [0, 1)."""
    d = np.abs(np.array([-1.0, 0.0, 1.0, 2.0]) - f)
    a = -0.5
    near = (a + 2) * d**3 - (a + 3) * d**2 + 1
    far = a * d**3 - 5 * a * d**2 + 8 * a * d - 4 * a
    return np.where(d <= 1, near, np.where(d < 2, far, 0.0))


def shifted_window(img: np.ndarray, box, t) -> np.ndarray:
    """img(x + t) over box (y0, y1, x0, x1), bicubic, exact in the fraction (cv2.remap rounds positions to
    1/32 px, which would cap the precision of the sub-pixel estimate). Samples outside repeat the border."""
    y0, y1, x0, x1 = box
    ix, iy = int(np.floor(t[0])), int(np.floor(t[1]))
    wx, wy = _keys(t[0] - ix), _keys(t[1] - iy)
    pad = np.pad(img, 2 + max(abs(ix), abs(iy)), mode="edge") if (
        y0 + iy - 1 < 0 or x0 + ix - 1 < 0 or y1 + iy + 2 > img.shape[0] or x1 + ix + 2 > img.shape[1]) else None
    src, o = (img, 0) if pad is None else (pad, 2 + max(abs(ix), abs(iy)))
    rows = src[o + y0 + iy - 1:o + y1 + iy + 2]
    cols = sum(wx[i] * rows[:, o + x0 + ix - 1 + i:o + x1 + ix - 1 + i] for i in range(4))
    return sum(wy[i] * cols[i:i + (y1 - y0)] for i in range(4)).astype(np.float32)


def _lk_level(I0: np.ndarray, I1: np.ndarray, t: np.ndarray, iterations: int, rows, tol: float):
    """Gauss-Newton on sum (I1(x + t) - I0(x))^2 over the band of I0, translation only (eq. 27)."""
    h, w = I0.shape
    m = int(np.ceil(np.abs(t).max())) + 2
    y0, y1, x0, x1 = _band(I0.shape, rows, min(m, w // 3), min(m, h // 3))
    gx = cv2.Sobel(I0, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)[y0:y1, x0:x1]
    gy = cv2.Sobel(I0, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)[y0:y1, x0:x1]
    T = I0[y0:y1, x0:x1]
    H = np.array([[np.sum(gx * gx), np.sum(gx * gy)], [np.sum(gx * gy), np.sum(gy * gy)]], float)
    if abs(np.linalg.det(H)) < 1e-9:
        return t, float("nan"), 0
    Hinv = np.linalg.inv(H)
    rms, k = float("nan"), 0
    for k in range(1, iterations + 1):
        W = shifted_window(I1, (y0, y1, x0, x1), t)
        e = W - T
        dt = Hinv @ np.array([np.sum(gx * e), np.sum(gy * e)], float)
        t = t - dt  # inverse compositional: I1(x + t) = I0(x + dt)  =>  t <- t - dt
        rms = float(np.sqrt(np.mean(e * e)))
        if np.abs(dt).max() < tol:
            break
    return t, rms, k


def lucas_kanade(I0: np.ndarray, I1: np.ndarray, init=(0.0, 0.0), levels: int = 3, iterations: int = 10,
                 rows=None, tol: float = 1e-3) -> Shift:
    """Hierarchical (coarse to fine) translational Lucas-Kanade starting from `init`."""
    p0, p1 = _pyramid(I0, levels), _pyramid(I1, levels)
    n = len(p0)
    t = np.asarray(init, float) / 2 ** (n - 1)
    rms, total = float("nan"), 0
    for lev in range(n - 1, -1, -1):
        f = 2 ** lev
        band = None if rows is None else (rows[0] / f, rows[1] / f)
        t, rms, k = _lk_level(p0[lev], p1[lev], t, iterations, band, tol)
        total += k
        if lev:
            t = t * 2
    return Shift(t, rms, total)


def hybrid(I0: np.ndarray, I1: np.ndarray, search=(16, 8), prior=(0, 0), metric: Metric = "zncc", iterations: int = 10,
           rows=None, tol: float = 1e-3, min_zncc: float = 0.5) -> Shift:
    """Full search for the integer shift (adaptive_full_search), then LK refinement on the finest level (no
    pyramid)."""
    coarse = adaptive_full_search(I0, I1, search, prior, metric, rows, min_zncc)
    fine = lucas_kanade(I0, I1, coarse.t, levels=1, iterations=iterations, rows=rows, tol=tol)
    if not np.all(np.isfinite(fine.t)) or np.abs(fine.t - coarse.t).max() > 1.0:
        return coarse  # the full search is within a pixel of the optimum: a refinement beyond that diverged
    return fine
