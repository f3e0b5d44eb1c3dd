"""The wall's radius by photo-consistency: a plane sweep along the wall normal for every cell of a slice's ring.

Each cell is a patch of the wall `dense_patch_m` square (along x around), centred every `dense_cell_m` around
the ring at the slice. The patch is moved along the wall normal through radii R +- dense_search_m in steps of
dense_step_m; at each radius its points are projected into the keyframes that see it (the poses fixed, as the
VO left them) and sampled every `dense_sample_m`; with `dense_subsamples` > 1 each sample is the mean of
that many points squared over its square of wall (area sampling; on deformed-pipe 2 read no better than 1
and cost 15 times as much, so 1 is the default: at 1.5 mm samples no view used sees the wall coarser than
about 2 mm a pixel).

The reference view is the one that sees the cell nearest `dense_ref_deg` off its axis (the fisheye sees the
wall best there: sharp, not grazing). The others see it between dense_ref_deg + `dense_parallax_deg` and
`dense_max_deg`: nearer the cell, so the pair has a baseline of up to a radius and a 1 mm move of the wall
shifts the cell's image in them by about a pixel. Per view the cost is 1 - ZNCC of the patch with the
reference's (the LED light moves with the camera: ZNCC ignores gain and offset); the views' costs are
aggregated by their median (a view that sees the patch under a highlight or through motion blur does not
decide). Each cell's radius is the sweep's least cost, refined by a parabola through its neighbours; a cell
whose best correlation stays under `dense_min_zncc`, or whose least cost lies at the sweep's end, has none.
The rings of radii (`dense_rings` side by side along the pipe, all cells together) then give the
slice's ovality, diameters and dent as for the sparse points.
Everything is vectorised over radii, cells and samples; the loop runs over the views.
"""

from __future__ import annotations

import warnings

import numpy as np

from pipemap.config import DeformationSettings
from pipemap.mapping.appearance import bilinear
from pipemap.mapping.deformation import SliceProfile, ring_fit, ring_profile, slice_positions, smooth_centre
from pipemap.mapping.wall import WallPiece


def patch_points(piece: WallPiece, h_c: float, radii: np.ndarray, s: DeformationSettings, radius: float):
    """World points (radii, cells, samples, subsamples, 3) of the ring of patches at h_c, and the cells' phi."""
    n_cells = max(36, int(round(2 * np.pi * radius / s.dense_cell_m)))
    phi = np.arange(n_cells) * (2 * np.pi / n_cells)
    n = max(1, int(round(s.dense_patch_m / s.dense_sample_m)))
    k = s.dense_subsamples
    centres = (np.arange(n) - (n - 1) / 2) * s.dense_sample_m
    sub = (np.arange(k) - (k - 1) / 2) * (s.dense_sample_m / k)
    # sample (i, j), subsample (a, b): along centres[i] + sub[a], around centres[j] + sub[b]
    along = np.broadcast_to((centres[:, None] + sub[None, :])[:, None, :, None], (n, n, k, k))
    around = np.broadcast_to((centres[:, None] + sub[None, :])[None, :, None, :], (n, n, k, k))
    along, around = along.reshape(n * n, k * k), around.reshape(n * n, k * k)
    u, e_up, e_cw = piece.frame()
    h = h_c + along
    axis = piece.start + h[..., None] * u + piece.axis_offset(h)  # (samples, sub, 3)
    ang = phi[:, None, None] + around[None] / radius  # (cells, samples, sub)
    radial = np.cos(ang)[..., None] * e_up + np.sin(ang)[..., None] * e_cw
    pts = axis[None, None] + radii[:, None, None, None, None] * radial[None]
    return pts, phi


def colatitudes(poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Angle (views, points) between each camera's axis and its ray to each world point (points, 3)."""
    X = np.einsum("kji,knj->kni", poses[:, :3, :3], points[None] - poses[:, None, :3, 3])
    return np.degrees(np.arctan2(np.hypot(X[..., 0], X[..., 1]), X[..., 2]))


def choose_views(theta: np.ndarray, s: DeformationSettings) -> tuple[np.ndarray, np.ndarray]:
    """Per cell (theta: views x cells, degrees; NaN where unseen), the reference view (-1: none within
    dense_parallax_deg of dense_ref_deg) and a mask (views, cells) of the views compared with it: at least
    dense_parallax_deg nearer the side than the reference, at most dense_max_deg, up to dense_views - 1 of
    them spread evenly over that range."""
    ok = np.isfinite(theta)
    gap = np.where(ok, np.abs(theta - s.dense_ref_deg), np.inf)
    ref = np.argmin(gap, axis=0)
    cells = np.arange(theta.shape[1])
    ref = np.where(gap[ref, cells] <= s.dense_parallax_deg, ref, -1)
    keep = np.zeros(theta.shape, bool)
    for c in np.flatnonzero(ref >= 0):
        lo = theta[ref[c], c] + s.dense_parallax_deg
        cand = np.flatnonzero(ok[:, c] & (theta[:, c] >= lo) & (theta[:, c] <= s.dense_max_deg))
        cand = cand[np.argsort(theta[cand, c])]
        if len(cand) > s.dense_views - 1:
            cand = cand[np.round(np.linspace(0, len(cand) - 1, s.dense_views - 1)).astype(int)]
        keep[cand, c] = True
    return ref, keep


def sample_view(camera, image: np.ndarray, pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Area-sampled grey levels (radii, cells, samples) of the patches in one view (NaN where any subsample
    falls outside the image or the fisheye's field)."""
    shape = pts.shape[:-1]
    X = (pts.reshape(-1, 3) - pose[:3, 3]) @ pose[:3, :3]
    uv, valid = camera.project(X)
    v = np.where(valid, bilinear(image, np.where(valid[:, None], uv, 0.0)), np.nan).reshape(shape)
    return v.mean(axis=-1)


def shading_free(v: np.ndarray) -> np.ndarray:
    """Patches (..., n*n) less their least-squares plane over the patch: the LED light falls off across a
    patch differently in each view, a gradient that ZNCC's gain and offset do not take out."""
    n = int(round(np.sqrt(v.shape[-1])))
    i, j = np.divmod(np.arange(n * n), n)
    A = np.stack([np.ones(n * n), i - i.mean(), j - j.mean()], axis=1)
    return v - v @ (A @ np.linalg.pinv(A)).T


def zncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """ZNCC over the last axis of the patches less their shading planes (NaN where either patch has a
    missing sample or no texture)."""
    a0 = shading_free(a)
    b0 = shading_free(b)
    den = np.sqrt((a0 * a0).sum(axis=-1) * (b0 * b0).sum(axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 1e-9, (a0 * b0).sum(axis=-1) / den, np.nan)


def sweep(camera, images: list[np.ndarray], poses: np.ndarray, pts: np.ndarray, ref: np.ndarray,
          keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per cell the median over its compared views of 1 - ZNCC with its reference, (radii, cells), and the
    number of views that gave it."""
    samples = np.stack([sample_view(camera, img, T, pts) for img, T in zip(images, poses)])  # (V, r, c, n)
    cells = np.arange(pts.shape[1])
    reference = samples[ref, :, cells].transpose(1, 0, 2)  # (r, c, n)
    cost = np.full((len(images),) + pts.shape[:2], np.nan)
    for v in range(len(images)):
        if keep[v].any():
            cost[v][:, keep[v]] = 1.0 - zncc(reference[:, keep[v]], samples[v][:, keep[v]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a cell no view measures: an all-NaN median
        return np.nanmedian(cost, axis=0), np.isfinite(cost).sum(axis=0)


def best_radius(cost: np.ndarray, radii: np.ndarray, min_zncc: float) -> np.ndarray:
    """(cells,) radius of least cost per cell, refined by a parabola through its neighbours (NaN at the
    sweep's ends, where the wall lies outside the search, and where the best correlation is weak)."""
    filled = np.where(np.isfinite(cost), cost, np.inf)
    k = np.argmin(filled, axis=0)
    cols = np.arange(cost.shape[1])
    inner = (k > 0) & (k < len(radii) - 1)
    kk = np.clip(k, 1, len(radii) - 2)
    c0, c1, c2 = cost[kk - 1, cols], cost[kk, cols], cost[kk + 1, cols]
    den = c0 - 2 * c1 + c2
    with np.errstate(invalid="ignore"):
        shift = np.where(den > 0, 0.5 * (c0 - c2) / np.where(den > 0, den, 1.0), 0.0)
    r = radii[kk] + np.clip(shift, -0.5, 0.5) * (radii[1] - radii[0])
    good = inner & np.isfinite(c0 + c1 + c2) & (1.0 - c1 >= min_zncc)
    return np.where(good, r, np.nan)


def slice_radii(piece: WallPiece, h_c: float, camera, poses: np.ndarray, image_of, radius: float,
                s: DeformationSettings) -> tuple[np.ndarray, np.ndarray]:
    """(phi, radius) of the ring of cells at h_c (radius NaN where no view pair measures it)."""
    radii = radius + np.arange(-s.dense_search_m, s.dense_search_m + 1e-12, s.dense_step_m)
    pts, phi = patch_points(piece, h_c, radii, s, radius)
    centres = piece.wall_points(np.array([h_c]), phi)[0]
    theta = colatitudes(poses, centres)
    _, seen = camera.project(np.einsum("kji,knj->kni", poses[:, :3, :3], centres[None] - poses[:, None, :3, 3]))
    theta[~seen] = np.nan
    ref, keep = choose_views(theta, s)
    measured = (ref >= 0) & keep.any(axis=0)
    if not measured.any():
        return phi, np.full(len(phi), np.nan)
    keep[:, ~measured] = False
    used = np.union1d(np.flatnonzero(keep.any(axis=1)), ref[measured])
    index = np.full(len(poses), -1)
    index[used] = np.arange(len(used))
    cost, _ = sweep(camera, [image_of(int(k)) for k in used], poses[used], pts, np.maximum(index[ref], 0),
                    keep[used])
    return phi, best_radius(cost, radii, s.dense_min_zncc)


def dense_profiles(piece: WallPiece, camera, poses: np.ndarray, image_of, radius: float,
                   s: DeformationSettings) -> list[SliceProfile]:
    """The piece's slices from the dense sweep; `image_of(row)` gives keyframe row's grey image."""
    cache: dict[int, np.ndarray] = {}

    def cached(k: int) -> np.ndarray:
        if k not in cache:
            cache[k] = np.asarray(image_of(k), np.float32)
        return cache[k]

    rings = (np.arange(s.dense_rings) - (s.dense_rings - 1) / 2) * s.dense_patch_m
    slices = []
    for h_c in slice_positions(piece, s):
        phi, r = zip(*(slice_radii(piece, h_c + dh, camera, poses, cached, radius, s) for dh in rings))
        phi, r = np.concatenate(phi), np.concatenate(r)
        fit = ring_fit(phi, r, s)
        if fit is not None:
            slices.append((float(h_c), phi[fit[1]], r[fit[1]], fit[0]))
        if len(cache) > 8 * s.dense_views:  # the slices move on along the pipe: forget the oldest views
            for k in sorted(cache)[: len(cache) - 4 * s.dense_views]:
                del cache[k]
    return ring_slices(slices, radius, s, piece.name)


def ring_slices(slices: list, radius: float, s: DeformationSettings, piece: str) -> list[SliceProfile]:
    """Slices (h, phi, r of the cells kept, Fourier coefficients) as profiles: the largest deviations are the
    medians of `bin_deg` cells around, about the centre that follows the slices' first harmonic smoothly along
    the piece (a dent's own first harmonic would otherwise take out part of it)."""
    if not slices:
        return []
    hs = np.array([g[0] for g in slices])
    centre = smooth_centre(hs, np.array([g[3][1:3] for g in slices]), s.centre_window_m)
    out = []
    for (h_c, phi, r, coef), c in zip(slices, centre):
        d = r - radius - np.cos(phi) * c[0] - np.sin(phi) * c[1]
        b = np.floor(np.mod(phi, 2 * np.pi) / np.radians(s.bin_deg)).astype(np.int64)
        medians = np.array([np.median(d[b == k]) for k in np.unique(b)])
        out.append(ring_profile(h_c, coef, len(r), piece, "dense", -medians.min(), medians.max(), s.harmonics))
    return out
