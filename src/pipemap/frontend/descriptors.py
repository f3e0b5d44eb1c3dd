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
    sim = desc_i @ desc_j.T
    if max_flow_px is not None and points_i is not None and points_j is not None:
        pi = np.asarray(points_i, np.float32)
        pj = np.asarray(points_j, np.float32)
        far = np.float32(max_flow_px**2)
        # 64 rows at a time, so that the squared distances stay in cache (each entry is its own test)
        for s in range(0, len(pi), 64):
            d2 = np.subtract.outer(pi[s:s + 64, 0], pj[:, 0])
            np.multiply(d2, d2, out=d2)
            dy = np.subtract.outer(pi[s:s + 64, 1], pj[:, 1])
            np.multiply(dy, dy, out=dy)
            d2 += dy
            np.putmask(sim[s:s + 64], d2 > far, -2.0)
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
