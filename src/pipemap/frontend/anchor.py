"""Re-locating continued tracks against their first appearance (anchor templates).

Keyframe-to-keyframe ZNCC takes each template from the previous keyframe, so a track's sub-pixel
errors add up along it like a random walk with a drift: measured against the simulator's ground
truth, tracks 16 or more keyframes long lay 0.8 px RMS off any single 3D point (0.2 px for 2-4
keyframes), and those long tracks bent every tee of a loop by tenths of a degree. Here every
continued track is matched once more against the patch it had in the keyframe where it was first
seen, so that its error no longer grows with its length.

Lucas-Kanade in its forward-additive form (Baker & Matthews 2004) with an affine warp, since the
fisheye compresses and stretches a patch as it crosses the view, and a gain and an offset for the
light that moves with the robot. The warp found at one keyframe starts the search at the next.
A result that moves more than `max_shift_px` from the ZNCC position, or whose warped patch
correlates with the template below `min_zncc`, keeps the ZNCC position and its previous warp.
"""

from __future__ import annotations

import cv2
import numpy as np

_PARAMS = 8  # du, dv, four affine terms, gain, offset


def _offsets(patch: int) -> np.ndarray:
    half = patch // 2
    o = np.arange(-half, half + 1, dtype=np.float32)
    gy, gx = np.meshgrid(o, o, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=1)  # (P, 2) as (u, v)


def _sample(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples of `image` at (u, v), edges clamped. Exact to float32: cv2.remap rounds the
    fractional position to 1/32 px, which alone leaves matches 0.03 px off."""
    h, w = image.shape
    u = np.clip(np.asarray(u, np.float32), 0, w - 1.001)
    v = np.clip(np.asarray(v, np.float32), 0, h - 1.001)
    u0, v0 = u.astype(np.int32), v.astype(np.int32)
    a, b = u - u0, v - v0
    flat = image.ravel()
    i = v0 * w + u0
    top = flat[i] * (1 - a) + flat[i + 1] * a
    bottom = flat[i + w] * (1 - a) + flat[i + w + 1] * a
    return top * (1 - b) + bottom * b


def anchor_templates(image: np.ndarray, points: np.ndarray, patch: int) -> np.ndarray:
    """(N, patch^2) float32 patches of `image` centred on `points` (N, 2), bilinear."""
    pts = np.asarray(points, np.float32).reshape(-1, 2)
    g = _offsets(patch)
    if len(pts) == 0:
        return np.zeros((0, len(g)), np.float32)
    image = np.ascontiguousarray(image, np.float32)
    return _sample(image, pts[:, 0, None] + g[None, :, 0], pts[:, 1, None] + g[None, :, 1])


def identity_warps(n: int) -> np.ndarray:
    return np.tile(np.eye(2, dtype=np.float32), (n, 1, 1))


def refine_to_anchors(image: np.ndarray, templates: np.ndarray, positions: np.ndarray, warps: np.ndarray,
                      patch: int, iterations: int = 10, max_shift_px: float = 1.5,
                      min_zncc: float = 0.7) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ok (N,), positions (N, 2), warps (N, 2, 2)) of the templates (N, patch^2) in `image`, starting
    from `positions` (N, 2) and `warps` (N, 2, 2); rows that fail keep their inputs."""
    pos0 = np.asarray(positions, np.float64).reshape(-1, 2)
    n = len(pos0)
    A0 = np.asarray(warps, np.float64).reshape(n, 2, 2)
    if n == 0:
        return np.zeros(0, bool), pos0.copy(), A0.copy()
    image = np.ascontiguousarray(image, np.float32)
    T = np.asarray(templates, np.float32)
    g = _offsets(patch)
    du = cv2.Scharr(image, cv2.CV_32F, 1, 0, scale=1.0 / 32.0)
    dv = cv2.Scharr(image, cv2.CV_32F, 0, 1, scale=1.0 / 32.0)
    p, A = pos0.copy(), A0.copy()
    gain, offset = np.ones(n), np.zeros(n)
    live = np.ones(n, bool)
    eye = np.eye(_PARAMS)
    for _ in range(iterations):
        idx = np.flatnonzero(live)
        if idx.size == 0:
            break
        where = p[idx, None, :] + np.einsum("pk,njk->npj", g, A[idx])
        u, v = where[..., 0], where[..., 1]
        I = _sample(image, u, v)
        Gu = _sample(du, u, v) * gain[idx, None].astype(np.float32)
        Gv = _sample(dv, u, v) * gain[idx, None].astype(np.float32)
        r = gain[idx, None].astype(np.float32) * I + offset[idx, None].astype(np.float32) - T[idx]
        J = np.stack([Gu, Gv, Gu * g[:, 0], Gu * g[:, 1], Gv * g[:, 0], Gv * g[:, 1], I, np.ones_like(I)], axis=2)
        H = np.einsum("npa,npb->nab", J, J, dtype=np.float64)
        b = np.einsum("npa,np->na", J, r, dtype=np.float64)
        H += eye * (1e-6 * np.trace(H, axis1=1, axis2=2) / _PARAMS + 1e-9)[:, None, None]
        d = -np.linalg.solve(H, b[..., None])[..., 0]
        p[idx] += d[:, :2]
        A[idx] += d[:, 2:6].reshape(-1, 2, 2)
        gain[idx] += d[:, 6]
        offset[idx] += d[:, 7]
        live[idx] = np.linalg.norm(d[:, :2], axis=1) > 1e-3
    where = p[:, None, :] + np.einsum("pk,njk->npj", g, A)
    I = _sample(image, where[..., 0], where[..., 1]).astype(np.float64)
    Ic, Tc = I - I.mean(axis=1, keepdims=True), T - T.mean(axis=1, keepdims=True)
    zncc = np.sum(Ic * Tc, axis=1) / (np.linalg.norm(Ic, axis=1) * np.linalg.norm(Tc, axis=1) + 1e-12)
    det = np.linalg.det(A)
    ok = (np.all(np.isfinite(p), axis=1) & (np.linalg.norm(p - pos0, axis=1) <= max_shift_px) & (zncc >= min_zncc)
          & (det > 0.25) & (det < 4.0))
    return ok, np.where(ok[:, None], p, pos0), np.where(ok[:, None, None], A, A0)


__all__ = ["anchor_templates", "identity_warps", "refine_to_anchors"]
