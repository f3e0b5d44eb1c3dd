"""The wall's radius by photo-consistency: a cylinder sweep at each deformation slice.

For the ring of wall cells at a slice (cells of `dense_cell_m` around the circle, a band of
`dense_window_cells` cells along), the wall is moved through radii R +- dense_search_m in steps of
dense_step_m. At each radius every cell is projected into `dense_views` keyframes that see the ring (the
poses fixed, as the VO left them) and the views' grey levels are compared with the first one by
zero-mean normalised cross-correlation over a window of cells (the LED light moves with the camera, so
brightness differs between views; ZNCC ignores gain and offset). Each cell's radius is the sweep's least
cost, refined by a parabola through its neighbours. The views span the widest range of distances to the
ring: a radial move of the wall shifts its image by different amounts in near and far views.
Everything is vectorised over cells and radii; the loop runs over the views.

Known limit (measured on deformed-pipe, short route, 640 x 480): the cells' radii are not yet a measurement.
Per view pair at the best radius ZNCC is only 0.3-0.7 and the median radius error 7-12 mm in a +-20 mm search,
for every pair from 5 cm to 45 cm apart, so neither the far views' grazing footprint alone nor the choice of
views decides it (views within 1 or 1.5 radii: the same); blurring every view to a common footprint made it
worse. A 1 mm radial move shifts the ring's image by only about 0.25 px between the nearest pair, while a 3 mm
cell is 1-1.5 px across: the window of 5 x 5 point-sampled cells holds too little texture at that precision,
and the reference view sees the ring 75-95 deg off its axis. Next: per-view sampling at each cell's footprint
(area, not point), a reference view at about 45 deg, and sub-pixel matching along the epipolar direction.
"""

from __future__ import annotations

import cv2
import numpy as np

from pipemap.config import DeformationSettings
from pipemap.mapping.appearance import bilinear
from pipemap.mapping.deformation import SliceProfile, profile, slice_positions
from pipemap.mapping.wall import WallPiece

# Views farther than this (in radii) see the ring at small colatitudes, a few pixels across a cell.
REACH_RADII = 3.0


def ring_points(piece: WallPiece, h_c: float, radii: np.ndarray, s: DeformationSettings, radius: float):
    """World points (radii, along, around, 3) of the ring at h_c, and the cells' phi (around,)."""
    n_phi = max(36, int(round(2 * np.pi * radius / s.dense_cell_m)))
    phi = np.arange(n_phi) * (2 * np.pi / n_phi)
    half = s.dense_window_cells // 2
    h = h_c + s.dense_cell_m * np.arange(-half, half + 1)
    u, e_up, e_cw = piece.frame()
    axis = piece.start + h[:, None] * u + piece.axis_offset(h)  # (along, 3)
    radial = np.cos(phi)[:, None] * e_up + np.sin(phi)[:, None] * e_cw  # (around, 3)
    pts = axis[None, :, None, :] + radii[:, None, None, None] * radial[None, None, :, :]
    return pts, phi


def choose_views(camera, poses: np.ndarray, centre_pts: np.ndarray, count: int, reach: float) -> np.ndarray:
    """Rows of `poses` within `reach` of the ring that see every cell of it (points (around, 3) at the
    a-priori radius), spread over the widest range of distance to it."""
    R = poses[:, :3, :3]
    c = poses[:, :3, 3]
    X = np.einsum("kji,knj->kni", R, centre_pts[None] - c[:, None])  # camera frame (views, around, 3)
    _, valid = camera.project(X)
    sees = np.flatnonzero(valid.all(axis=1) & (np.linalg.norm(c - centre_pts.mean(axis=0), axis=1) <= reach))
    if len(sees) < 2:
        return sees
    dist = np.linalg.norm(c[sees] - centre_pts.mean(axis=0), axis=1)
    order = sees[np.argsort(dist)]
    pick = np.unique(np.round(np.linspace(0, len(order) - 1, min(count, len(order)))).astype(int))
    return order[pick]


def sweep_ring(camera, images: list[np.ndarray], poses: np.ndarray, pts: np.ndarray, window: int) -> np.ndarray:
    """Cost (radii, around) of each radius per cell: the mean over views 2.. of 1 - ZNCC with view 1 over
    the band along and `window` cells around."""
    nr, na, nphi, _ = pts.shape
    samples = []
    for img, T in zip(images, poses):
        X = (pts.reshape(-1, 3) - T[:3, 3]) @ T[:3, :3]
        uv, valid = camera.project(X)
        v = bilinear(img, uv).reshape(nr, na, nphi)
        samples.append(np.where(valid.reshape(nr, na, nphi), v, np.nan))
    ref = samples[0]
    cost = np.zeros((nr, nphi))
    for other in samples[1:]:
        cost += 1.0 - _zncc(ref, other, window)
    return cost / max(len(samples) - 1, 1)


def _zncc(a: np.ndarray, b: np.ndarray, window: int) -> np.ndarray:
    """ZNCC (radii, around) over all rows along and `window` cells around (wrapping)."""
    def box(x):  # sum over the band and the window around, wrapping round the circle
        s = np.nansum(x, axis=1)
        pad = window // 2
        s = np.concatenate([s[:, -pad:], s, s[:, :pad]], axis=1) if pad else s
        out = cv2.boxFilter(s, -1, (window, 1), normalize=False, borderType=cv2.BORDER_CONSTANT)
        return out[:, pad:pad + x.shape[2]]

    ok = np.isfinite(a) & np.isfinite(b)
    a0, b0 = np.where(ok, a, 0.0), np.where(ok, b, 0.0)
    n = box(ok.astype(float))
    sa, sb = box(a0), box(b0)
    saa, sbb, sab = box(a0 * a0), box(b0 * b0), box(a0 * b0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = sab - sa * sb / n
        var = (saa - sa * sa / n) * (sbb - sb * sb / n)
        z = cov / np.sqrt(np.maximum(var, 1e-12))
    return np.where(n >= 0.8 * a.shape[1] * window, z, -1.0)


def best_radius(cost: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(around,) radius of least cost per cell, refined by a parabola through its neighbours (NaN at the
    sweep's ends: the wall lies outside the search)."""
    k = np.argmin(cost, axis=0)
    cols = np.arange(cost.shape[1])
    inner = (k > 0) & (k < len(radii) - 1)
    kk = np.clip(k, 1, len(radii) - 2)
    c0, c1, c2 = cost[kk - 1, cols], cost[kk, cols], cost[kk + 1, cols]
    den = c0 - 2 * c1 + c2
    shift = np.where(den > 0, 0.5 * (c0 - c2) / np.where(den > 0, den, 1.0), 0.0)
    r = radii[kk] + np.clip(shift, -1, 1) * (radii[1] - radii[0])
    return np.where(inner, r, np.nan)


def dense_profiles(piece: WallPiece, camera, poses: np.ndarray, image_of, radius: float,
                   s: DeformationSettings) -> list[SliceProfile]:
    """The piece's slices from the dense sweep; `image_of(row)` gives keyframe row's grey image."""
    radii = radius + np.arange(-s.dense_search_m, s.dense_search_m + 1e-12, s.dense_step_m)
    cache: dict[int, np.ndarray] = {}
    out = []
    for h_c in slice_positions(piece, s):
        pts, phi = ring_points(piece, h_c, radii, s, radius)
        centre = pts[len(radii) // 2, pts.shape[1] // 2]
        views = choose_views(camera, poses, centre, s.dense_views, REACH_RADII * radius)
        if len(views) < 3:
            continue
        images = []
        for k in views.tolist():
            if k not in cache:
                cache[k] = image_of(k)
            images.append(cache[k])
        cost = sweep_ring(camera, images, poses[views], pts, s.dense_window_cells)
        r = best_radius(cost, radii)
        p = profile(h_c, phi, r, radius, s, piece.name, "dense")
        if p is not None:
            out.append(p)
        if len(cache) > 4 * s.dense_views:  # the slices move on along the pipe: forget the oldest views
            for k in sorted(cache)[: len(cache) - 2 * s.dense_views]:
                del cache[k]
    return out
