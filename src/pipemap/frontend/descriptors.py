"""Grey template descriptors and their cosine-similarity matching (fisheye paper III-A).

A descriptor is an `size` x `size` grid of grey values sampled across the `window` x `window`
neighbourhood of a corner (11 x 11 from 31 x 31 in the paper), zero-mean and unit-norm, so that
the cosine similarity of two descriptors is their dot product and ignores gain and offset
changes of the robot's moving lights.
"""

from __future__ import annotations

import cv2
import numpy as np


def smooth_for_templates(image: np.ndarray, size: int = 11, window: int = 31) -> np.ndarray:
    """Box-filter the image once per frame so that point samples of it average like an area resize."""
    step = max(1, int(round(window / size)))
    image = np.ascontiguousarray(image, dtype=np.float32)
    return cv2.blur(image, (step, step)) if step > 1 else image


def describe(smoothed: np.ndarray, keypoints: np.ndarray, size: int = 11,
             window: int = 31) -> tuple[np.ndarray, np.ndarray]:
    """Descriptors (N, size*size) float32 of the corners `keypoints` (N, 2), and which are usable.

    All templates are sampled in one `cv2.remap` call. A flat patch (glare, no texture) has no
    direction and is marked unusable; its descriptor is zero.
    """
    keypoints = np.asarray(keypoints, dtype=np.float32).reshape(-1, 2)
    n = keypoints.shape[0]
    if n == 0:
        return np.zeros((0, size * size), np.float32), np.zeros(0, bool)
    offsets = np.linspace(-(window - 1) / 2.0, (window - 1) / 2.0, size, dtype=np.float32)
    map_x = keypoints[:, 0, None, None] + offsets[None, None, :]
    map_y = keypoints[:, 1, None, None] + offsets[None, :, None]
    map_x = np.ascontiguousarray(np.broadcast_to(map_x, (n, size, size)).reshape(n * size, size))
    map_y = np.ascontiguousarray(np.broadcast_to(map_y, (n, size, size)).reshape(n * size, size))
    samples = cv2.remap(smoothed, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT101)
    d = samples.reshape(n, size * size)
    d = d - d.mean(axis=1, keepdims=True)
    norm = np.linalg.norm(d, axis=1)
    usable = norm > 1e-3 * size
    d = np.where(usable[:, None], d / np.where(usable, norm, 1.0)[:, None], 0.0).astype(np.float32)
    return d, usable


def match_descriptors(
    desc_i: np.ndarray,
    desc_j: np.ndarray,
    points_i: np.ndarray | None = None,
    points_j: np.ndarray | None = None,
    ratio: float = 0.9,
    min_similarity: float = 0.5,
    max_flow_px: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mutual best cosine matches that pass the ratio test: (index_i (M,), index_j (M,), similarity (M,)).

    The ratio test compares cosine distances (1 - similarity) of the best and second-best
    candidate in image j. With `max_flow_px` only candidates within that pixel distance count.
    """
    empty = (np.zeros(0, int), np.zeros(0, int), np.zeros(0, np.float32))
    if len(desc_i) == 0 or len(desc_j) == 0:
        return empty
    if max_flow_px is None or points_i is None or points_j is None:
        return _mutual_ratio(desc_i @ desc_j.T, ratio, min_similarity)
    return _match_near(desc_i, desc_j, np.asarray(points_i, np.float32), np.asarray(points_j, np.float32), ratio,
                       min_similarity, max_flow_px)


def _mutual_ratio(sim: np.ndarray, ratio: float, min_similarity: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rows = np.arange(sim.shape[0])
    best_j = np.argmax(sim, axis=1)
    best = sim[rows, best_j].copy()
    best_i = np.argmax(sim, axis=0)
    sim[rows, best_j] = -3.0
    second = sim.max(axis=1) if sim.shape[1] > 1 else np.full_like(best, -2.0)
    mutual = best_i[best_j] == rows
    distinct = (1.0 - best) < ratio * (1.0 - second)
    good = mutual & distinct & (best >= min_similarity)
    return rows[good], best_j[good], best[good]


_BAND_ROWS = 64  # corners of image i matched at a time: their candidates' squared distances stay in cache


def _match_near(desc_i, desc_j, pi, pj, ratio: float, min_similarity: float, max_flow_px: float):
    """match_descriptors with candidates within max_flow_px: both images' corners taken in order of u, so that
    _BAND_ROWS corners of image i need only the band of image j's within max_flow_px of their u range (a third of
    the image at 640x480), and only that band's similarities are formed and searched."""
    far = np.float32(max_flow_px**2)
    oi, oj = np.argsort(pi[:, 0], kind="stable"), np.argsort(pj[:, 0], kind="stable")
    pi, pj, di, dj = pi[oi], pj[oj], desc_i[oi], desc_j[oj]
    n, m = len(pi), len(pj)
    best_j, best, second = np.zeros(n, np.int64), np.full(n, -2.0, np.float32), np.full(n, -2.0, np.float32)
    column_best, column_row = np.full(m, -2.0, np.float32), np.full(m, -1, np.int64)
    margin = max_flow_px + 1.0  # beyond it |du| alone puts a candidate out of reach, whatever the rounding
    for s in range(0, n, _BAND_ROWS):
        rows = slice(s, min(s + _BAND_ROWS, n))
        lo = int(np.searchsorted(pj[:, 0], pi[rows.start, 0] - margin, side="left"))
        hi = int(np.searchsorted(pj[:, 0], pi[rows.stop - 1, 0] + margin, side="right"))
        if hi <= lo:
            continue
        sim = di[rows] @ dj[lo:hi].T
        d2 = np.subtract.outer(pi[rows, 0], pj[lo:hi, 0])
        np.multiply(d2, d2, out=d2)
        dy = np.subtract.outer(pi[rows, 1], pj[lo:hi, 1])
        np.multiply(dy, dy, out=dy)
        d2 += dy
        np.putmask(sim, d2 > far, -2.0)
        r = np.arange(sim.shape[0])
        j = np.argmax(sim, axis=0)
        top = sim[j, np.arange(sim.shape[1])]
        better = top > column_best[lo:hi]
        column_best[lo:hi] = np.where(better, top, column_best[lo:hi])
        column_row[lo:hi] = np.where(better, j + s, column_row[lo:hi])
        k = np.argmax(sim, axis=1)
        best_j[rows], best[rows] = k + lo, sim[r, k]
        if sim.shape[1] > 1:
            sim[r, k] = -3.0
            second[rows] = sim.max(axis=1)
    mutual = column_row[best_j] == np.arange(n)
    good = np.flatnonzero(mutual & ((1.0 - best) < ratio * (1.0 - second)) & (best >= min_similarity))
    good = good[np.argsort(oi[good])]  # in image i's order, as without the band
    return oi[good], oj[best_j[good]], best[good]
