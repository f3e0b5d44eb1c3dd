"""The anchor match's inner loop, compiled: each track's inverse-compositional affine Lucas-Kanade.

anchor.py describes the match. Vectorised over tracks in numpy, every iteration wrote the warped sample
positions, the four bilinear neighbours, the patches and their residuals of every active track to memory
and read them back (at 1280x960, 23 x 23 patches, 100 ms a keyframe of 1200 tracks). Here one track at a time
runs its iterations with its patch in registers and cache; the GIL is released, so the frame reading beside
the tracking goes on.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# Sums may be reordered (vectorised); NaN and infinity keep their meaning, since a diverged track is refused by them.
_FAST = {"reassoc", "contract", "arcp", "nsz"}


@njit(cache=True, nogil=True, fastmath=_FAST)
def _sample(image, u, v, out):
    """Bilinear samples of `image` at (u, v), edges clamped as anchor.py's sampler; returns mean and norm of
    the patch after its mean is taken out (out holds the zero-mean samples)."""
    h, w = image.shape
    total = 0.0
    for i in range(u.shape[0]):
        x = min(max(u[i], 0.0), w - 1.001) if np.isfinite(u[i]) else 0.0
        y = min(max(v[i], 0.0), h - 1.001) if np.isfinite(v[i]) else 0.0
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        top = image[y0, x0] + (image[y0, x0 + 1] - image[y0, x0]) * fx
        bottom = image[y0 + 1, x0] + (image[y0 + 1, x0 + 1] - image[y0 + 1, x0]) * fx
        out[i] = top + (bottom - top) * fy
        total += out[i]
    mean = total / u.shape[0]
    norm = 0.0
    for i in range(u.shape[0]):
        out[i] -= mean
        norm += out[i] * out[i]
    return np.sqrt(norm)


@njit(cache=True, nogil=True, fastmath=_FAST)
def _positions(p, A, bend, offsets, u, v):
    for i in range(offsets.shape[0]):
        gx, gy = offsets[i, 0], offsets[i, 1]
        u[i] = p[0] + A[0, 0] * gx + A[0, 1] * gy + bend[0, i]
        v[i] = p[1] + A[1, 0] * gx + A[1, 1] * gy + bend[1, i]


@njit(cache=True, nogil=True, fastmath=_FAST)
def refine_tracks(image, templates, steepest, inverse_hessian, warps, bend, positions, offsets, iterations,
                  min_step_px):
    """Per track: iterate the warp (position (2,), linear part (2, 2)) towards its normalised template until
    the step is below `min_step_px` or `iterations` are done. Returns positions (N, 2), warps (N, 2, 2) and
    the final ZNCC (N,) against the template."""
    n, P = templates.shape
    p_out = positions.copy()
    A_out = warps.copy()
    zncc = np.zeros(n)
    u = np.empty(P)
    v = np.empty(P)
    patch = np.empty(P)
    d = np.empty(6)
    for k in range(n):
        p = p_out[k]
        A = A_out[k]
        for _ in range(iterations):
            _positions(p, A, bend[k], offsets, u, v)
            norm = max(_sample(image, u, v, patch), 1e-12)
            for i in range(P):
                patch[i] = patch[i] / norm - templates[k, i]
            for j in range(6):
                acc = 0.0
                for i in range(P):
                    acc += steepest[k, j, i] * patch[i]
                d[j] = acc
            step = inverse_hessian[k] @ d
            # W(x; p, A) <- W(x; p, A) o W(x; step)^-1, W(x; step) = x + D x + step_t
            m00, m01, m10, m11 = 1.0 + step[2], step[3], step[4], 1.0 + step[5]
            det = m00 * m11 - m01 * m10
            if not np.isfinite(det) or det == 0.0:  # a degenerate step: the track is refused (p not finite)
                p[0] = p[1] = np.nan
                break
            i00, i01, i10, i11 = m11 / det, -m01 / det, -m10 / det, m00 / det
            a00 = A[0, 0] * i00 + A[0, 1] * i10
            a01 = A[0, 0] * i01 + A[0, 1] * i11
            a10 = A[1, 0] * i00 + A[1, 1] * i10
            a11 = A[1, 0] * i01 + A[1, 1] * i11
            A[0, 0], A[0, 1], A[1, 0], A[1, 1] = a00, a01, a10, a11
            p[0] -= a00 * step[0] + a01 * step[1]
            p[1] -= a10 * step[0] + a11 * step[1]
            if max(abs(step[0]), abs(step[1])) < min_step_px:
                break
        _positions(p, A, bend[k], offsets, u, v)
        norm = max(_sample(image, u, v, patch), 1e-12)
        z = 0.0
        for i in range(P):
            z += patch[i] / norm * templates[k, i]
        zncc[k] = z
    return p_out, A_out, zncc
