"""Re-locating continued tracks against their first appearance (anchor templates).

Keyframe-to-keyframe ZNCC takes each template from the previous keyframe, so a track's sub-pixel
errors add up along it like a random walk with a drift: measured against the simulator's ground
truth, tracks 16 or more keyframes long lay 0.8 px RMS off any single 3D point (0.2 px for 2-4
keyframes), and those long tracks bent every tee of a loop by tenths of a degree. Here every
continued track is matched once more against the patch it had in the keyframe where it was first
seen, so that its error no longer grows with its length.

Lucas-Kanade in its inverse-compositional form (Baker & Matthews 2004) with an affine warp, since
the fisheye compresses and stretches a patch as it crosses the view: the steepest-descent images
and the Hessian belong to the template and are computed once, when the track starts. Both the
template and the warped patch are normalised to unit norm after the brightness terms are projected
out of them (`brightness_terms`): 1 takes out the offset (ZNCC), 3 a plane and 6 a quadratic in
the template's coordinates ("project out", Baker & Matthews). On log brightness the light that
moves with the robot is such a smooth term per patch, and a polynomial in the template's
coordinates is one in the warped patch's too, so the comparison stays the same as the patch is
stretched. A high-pass filter fixed in the image (the flattened image, `frontend.anchor_lighting`)
does not: as a patch is magnified it passes another band of the wall's texture and the match slides.
On paper-loop's first 800 frames, against the point that best fits each track from the true poses,
the matches lay 0.17 px RMS across the motion at a track's second observation and 0.30 px at its
ninth on the flattened image, 0.15 and 0.23 px on log brightness less a quadratic. The warp found
at one keyframe starts the search at the next.

The warp also carries a second-order term, predicted rather than solved for: between views of the
wall the image motion bends across a window, and an affine fit to a bent motion misplaces the
window's centre (+0.04 px outwards near the optical axis, -0.06 px inwards at 70-80 deg after a few
keyframes, which shortened every section). flow.py measures the bend from the neighbouring matches,
and `carry` composes it along the track.

A result that moves more than `max_shift_px` from the ZNCC position, whose warped patch correlates
with the template below `min_zncc`, or whose warp stretches the patch by more than `max_stretch`
along any direction, is refused (`ok` False: its inputs are returned), and the tracker ends that
track. Continued from the ZNCC position alone, such tracks were the ones that drifted (on
paper-loop, tracks of 16+ keyframes went from 0.8 to 0.2 px RMS off one point once they were ended
there). A patch first seen foreshortened, far down the pipe, fixes its point only loosely across
the foreshortening, and seen from close by that looseness is magnified: on paper-loop a third of
the tracks started within 30 deg of the optical axis later lay more than 1 px off their point, and
those observations alone moved the tee centres by about 0.05 %.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


# Tracks are warped and sampled this many pixels at a time: every row is independent, and a chunk's
# temporaries stay in the CPU cache.
_CHUNK_SAMPLES = 65536


def _offsets(patch: int) -> np.ndarray:
    half = patch // 2
    o = np.arange(-half, half + 1, dtype=np.float32)
    gy, gx = np.meshgrid(o, o, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=1)  # (P, 2) as (u, v)


class _Bilinear:
    """Bilinear samples of an image at float positions, edges clamped, exact to float32: cv2.remap's own
    bilinear mode rounds the fractional position to 1/32 px, which alone leaves matches 0.03 px off. Each
    pixel holds itself, its right neighbour less itself, its lower neighbour and its diagonal neighbour less
    the lower one (four channels), so that one nearest-neighbour remap at the integer positions gathers all
    four corners (2.6x cheaper than four numpy gathers) with the differences along each row already taken."""

    def __init__(self, image: np.ndarray):
        image = np.ascontiguousarray(image, np.float32)
        self.h, self.w = image.shape
        edge = cv2.BORDER_REPLICATE
        lower = cv2.copyMakeBorder(image[1:], 0, 1, 0, 0, edge)
        self.quad = cv2.merge([image, cv2.copyMakeBorder(image[:, 1:], 0, 0, 0, 1, edge) - image,
                               lower, cv2.copyMakeBorder(image[1:, 1:], 0, 1, 0, 1, edge) - lower])

    def __call__(self, u: np.ndarray, v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Samples at (u, v), written to `out` (their shape, float32) if given; u and v are float32 and are
        overwritten."""
        np.clip(u, 0, self.w - 1.001, out=u)
        np.clip(v, 0, self.h - 1.001, out=v)
        u0, v0 = np.floor(u), np.floor(v)
        u -= u0
        v -= v0
        q = cv2.remap(self.quad, u0, v0, cv2.INTER_NEAREST)
        top = np.multiply(q[..., 1], u)
        top += q[..., 0]
        bottom = np.multiply(q[..., 3], u, out=out)
        bottom += q[..., 2]
        bottom -= top
        bottom *= v
        bottom += top
        return bottom


BRIGHTNESS_TERMS = (1, 3, 6)  # offset; plane; quadratic


def _brightness_basis(patch: int, terms: int) -> np.ndarray:
    """(terms, P) orthonormal rows spanning the polynomials of the template's offsets up to the given terms."""
    if terms not in BRIGHTNESS_TERMS:
        raise ValueError(f"brightness terms must be one of {BRIGHTNESS_TERMS}, not {terms}")
    g = _offsets(patch).astype(np.float64)
    x, y = g[:, 0], g[:, 1]
    columns = [np.ones_like(x), x, y, x * x, x * y, y * y][:terms]
    q, _ = np.linalg.qr(np.stack(columns, axis=1))
    return np.ascontiguousarray(q.T, np.float32)


def _normalised(x: np.ndarray, basis: np.ndarray, overwrite: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Rows of x less their brightness terms (`basis`, one row: the mean) at unit norm, and their norms before
    scaling; with `overwrite` x itself becomes the result."""
    if len(basis) == 1:  # the mean, as the flattened image has always been compared
        terms = x.mean(axis=-1, keepdims=True)
    else:
        terms = (x @ basis.T) @ basis
    x = np.subtract(x, terms, out=x if overwrite else None)
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    x /= np.maximum(norm, 1e-12)
    return x, norm


@dataclass
class Anchors:
    """Per track: the normalised template (N, P), its steepest-descent images (N, 6, P) for the affine
    parameters (du, dv, a11, a12, a21, a22), the inverse Hessian (N, 6, 6), the current warp's linear
    part (N, 2, 2) and its second derivatives (N, 2, 2, 2): the warp takes template offset x to
    position + A x + 1/2 x^T C_k x in component k."""

    templates: np.ndarray
    steepest: np.ndarray
    inverse_hessian: np.ndarray
    warps: np.ndarray
    curvature: np.ndarray

    _FIELDS = ("templates", "steepest", "inverse_hessian", "warps", "curvature")

    def __len__(self) -> int:
        return len(self.templates)

    def take(self, rows) -> "Anchors":
        return Anchors(*(getattr(self, f)[rows] for f in self._FIELDS))

    @staticmethod
    def concatenate(parts: list["Anchors"]) -> "Anchors":
        return Anchors(*(np.concatenate([getattr(p, f) for p in parts]) for f in Anchors._FIELDS))

    def carry(self, jacobian: np.ndarray, hessian: np.ndarray) -> "Anchors":
        """The warps' second derivatives after one more image motion y -> S(y) with Jacobian (N, 2, 2)
        and second derivatives (N, 2, 2, 2) at each track: d2(S o W) = J_S d2W + A^T d2S A. The linear
        parts are left to the match."""
        A = self.warps.astype(np.float64)
        c = (np.einsum("nkj,njab->nkab", jacobian, self.curvature.astype(np.float64))
             + np.einsum("nia,nkij,njb->nkab", A, hessian, A))
        return Anchors(self.templates, self.steepest, self.inverse_hessian, self.warps, c.astype(np.float32))


def _shifted_windows(image: np.ndarray, points: np.ndarray, half: int) -> np.ndarray:
    """The (2 half + 1)^2 windows of `image` centred on `points` (N, 2), each shifted by its point's fraction
    of a pixel: bilinear samples, edges clamped. Every sample of a window shares the point's fraction, so one
    gather of the integer window one pixel larger and four weights give them all."""
    h, w = image.shape
    base = np.floor(points).astype(np.float32)
    a, b = (points - base)[:, 0, None, None], (points - base)[:, 1, None, None]
    o = np.arange(-half, half + 2, dtype=np.float32)
    k = len(o)
    cols = np.clip(base[:, 0, None, None] + o[None, None, :], 0, w - 1)
    rows = np.clip(base[:, 1, None, None] + o[None, :, None], 0, h - 1)
    grid = cv2.remap(image, np.ascontiguousarray(np.broadcast_to(cols, (len(points), k, k)).reshape(-1, k)),
                     np.ascontiguousarray(np.broadcast_to(rows, (len(points), k, k)).reshape(-1, k)),
                     cv2.INTER_NEAREST).reshape(-1, k, k)
    top = grid[:, :-1, :-1] + (grid[:, :-1, 1:] - grid[:, :-1, :-1]) * a
    bottom = grid[:, 1:, :-1] + (grid[:, 1:, 1:] - grid[:, 1:, :-1]) * a
    return top + (bottom - top) * b


def anchor_templates(image: np.ndarray, points: np.ndarray, patch: int, brightness_terms: int = 1) -> Anchors:
    """Anchors of the patches of `image` centred on `points` (N, 2), identity warps; `brightness_terms` as
    refine_to_anchors will be given."""
    pts = np.asarray(points, np.float32).reshape(-1, 2)
    g = _offsets(patch)
    n = len(pts)
    if n == 0:
        P = len(g)
        return Anchors(np.zeros((0, P), np.float32), np.zeros((0, 6, P), np.float32),
                       np.zeros((0, 6, 6), np.float32), np.zeros((0, 2, 2), np.float32),
                       np.zeros((0, 2, 2, 2), np.float32))
    image = np.ascontiguousarray(image, np.float32)
    half = patch // 2
    # Scharr commutes with the sub-pixel shift: the gradients of each shifted window (one pixel wider all
    # round, its ring dropped) are the image's gradients sampled at the template's pixels.
    wide = _shifted_windows(image, pts, half + 1)
    stack = wide.reshape(-1, patch + 2)
    inner = (slice(None), slice(1, -1), slice(1, -1))
    basis = _brightness_basis(patch, brightness_terms)
    T, norm = _normalised(wide[inner].reshape(n, -1), basis)
    scale = 1.0 / np.maximum(norm, 1e-12)
    gu = cv2.Scharr(stack, cv2.CV_32F, 1, 0, scale=1.0 / 32.0).reshape(wide.shape)[inner].reshape(n, -1) * scale
    gv = cv2.Scharr(stack, cv2.CV_32F, 0, 1, scale=1.0 / 32.0).reshape(wide.shape)[inner].reshape(n, -1) * scale
    sd = np.stack([gu, gv, gu * g[:, 0], gu * g[:, 1], gv * g[:, 0], gv * g[:, 1]], axis=1)
    if brightness_terms > 1:  # the residuals lie outside the brightness terms, so must the descent directions
        sd = sd - (sd @ basis.T) @ basis
    H = np.matmul(sd, sd.transpose(0, 2, 1)).astype(np.float64)
    H += np.eye(6) * (1e-6 * np.trace(H, axis1=1, axis2=2) / 6 + 1e-12)[:, None, None]
    return Anchors(T.astype(np.float32), sd, np.linalg.inv(H).astype(np.float32),
                   np.tile(np.eye(2, dtype=np.float32), (n, 1, 1)), np.zeros((n, 2, 2, 2), np.float32))


def _warped_patches(sample: _Bilinear, p: np.ndarray, A: np.ndarray, bend: np.ndarray, g: np.ndarray,
                    basis: np.ndarray) -> np.ndarray:
    """The normalised patches (N, P) of the warps (p, A) with their fixed second-order parts `bend` (N, 2, P)."""
    a = A.astype(np.float32)
    out = np.empty((len(p), len(g)), np.float32)
    step = max(1, _CHUNK_SAMPLES // len(g))
    for rows in (slice(s, s + step) for s in range(0, len(p), step)):
        a_, b_ = a[rows], bend[rows]
        term = np.empty((len(a_), len(g)), np.float32)
        u = np.multiply(a_[:, 0, 0, None], g[:, 0])
        u += np.float32(p[rows, 0, None])
        u += np.multiply(a_[:, 0, 1, None], g[:, 1], out=term)
        u += b_[:, 0]
        v = np.multiply(a_[:, 1, 0, None], g[:, 0])
        v += np.float32(p[rows, 1, None])
        v += np.multiply(a_[:, 1, 1, None], g[:, 1], out=term)
        v += b_[:, 1]
        _normalised(sample(u, v, out=out[rows]), basis, overwrite=True)
    return out


def _inverse_2x2(M: np.ndarray) -> np.ndarray:
    """Inverses of 2x2 matrices (N, 2, 2) by their adjugates (a singular one gives inf or nan, refused later)."""
    adj = np.stack([M[:, 1, 1], -M[:, 0, 1], -M[:, 1, 0], M[:, 0, 0]], axis=1).reshape(-1, 2, 2)
    return adj / (M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0])[:, None, None]


def refine_to_anchors(image: np.ndarray, anchors: Anchors, positions: np.ndarray, patch: int, iterations: int = 6,
                      max_shift_px: float = 1.5, min_zncc: float = 0.7,
                      max_stretch: float = 4.0, brightness_terms: int = 1) -> tuple[np.ndarray, np.ndarray, Anchors]:
    """(ok (N,), positions (N, 2), anchors with the new warps) of the anchors in `image`, starting from
    `positions` (N, 2) and the anchors' warps; rows that fail keep their position and warp. A track stops
    iterating once its step is below 1e-3 px. `brightness_terms` must be the templates' own."""
    pos0 = np.asarray(positions, np.float64).reshape(-1, 2)
    n = len(pos0)
    if n == 0:
        return np.zeros(0, bool), pos0.copy(), anchors
    sample = _Bilinear(image)
    g = _offsets(patch)
    basis = _brightness_basis(patch, brightness_terms)
    p, A = pos0.copy(), anchors.warps.astype(np.float64)
    # the fixed second-order part of the warp, per track and template pixel: 1/2 x^T C_k x
    squares = (g[:, :, None] * g[:, None, :]).reshape(len(g), 4)
    bend = 0.5 * np.matmul(anchors.curvature.reshape(n, 2, 4), squares.T)
    active = np.arange(n)
    with np.errstate(over="ignore", invalid="ignore"):  # a runaway warp is refused below
        for _ in range(iterations):
            rows = slice(None) if len(active) == n else active  # a slice takes no copy of the anchors
            r = _warped_patches(sample, p[rows], A[rows], bend[rows], g, basis) - anchors.templates[rows]
            d = np.matmul(anchors.inverse_hessian[rows], np.matmul(anchors.steepest[rows], r[:, :, None]))
            d = d[:, :, 0].astype(np.float64)
            # W(x; p, A) <- W(x; p, A) o W(x; d)^-1, W(x; d) = x + D x + d_t
            A_new = A[rows] @ _inverse_2x2(np.eye(2) + d[:, 2:6].reshape(-1, 2, 2))
            p[rows] -= np.einsum("nij,nj->ni", A_new, d[:, :2])
            A[rows] = A_new
            active = active[np.abs(d[:, :2]).max(axis=1) >= 1e-3]
            if not len(active):
                break
    # a warp that ran away (matched against what is not its patch) must not reach the SVD, which fails on it
    finite = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(A), axis=(1, 2)) & (np.abs(A).max(axis=(1, 2)) < 1e6)
    A = np.where(finite[:, None, None], A, np.eye(2))
    p = np.where(finite[:, None], p, pos0)
    zncc = np.sum(_warped_patches(sample, p, A, bend, g, basis) * anchors.templates, axis=1)
    sv = np.linalg.svd(A, compute_uv=False)
    ok = (finite & (np.linalg.norm(p - pos0, axis=1) <= max_shift_px) & (zncc >= min_zncc)
          & (np.linalg.det(A) > 0) & (sv[:, 0] <= max_stretch) & (sv[:, 1] >= 1.0 / max_stretch))
    warps = np.where(ok[:, None, None], A, anchors.warps).astype(np.float32)
    out = Anchors(anchors.templates, anchors.steepest, anchors.inverse_hessian, warps, anchors.curvature)
    return ok, np.where(ok[:, None], p, pos0), out


__all__ = ["BRIGHTNESS_TERMS", "Anchors", "anchor_templates", "refine_to_anchors"]
