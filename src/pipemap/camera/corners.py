"""Checkerboard inner corners: OpenCV finds the grid, a point-symmetry fit in board coordinates places each corner.

A checkerboard is point-symmetric about every inner corner: I(c + d) = I(c - d) for offsets d within a square.
Blur, a clipped (overexposed) white and any monotone response curve keep that symmetry, and so does any
locally affine view of the board. A gradient criterion such as cv2.cornerSubPix does not survive them: where
blur and a clipped white have eaten the black squares' tips, so that they no longer touch, its window (square
in the image, while the squares are compressed several times radially) settles on one tip or between the
edges. On the real 190 deg views that cost 1.16 px RMS, on blurred overexposed renders 1.5 px at the median;
the symmetry fit gives 0.26 px and 0.03 px.
So each corner is placed where the image, sampled on the board's own grid, is most symmetric. The grid near a
corner is a quadratic map from board coordinates to pixels fitted to its 3x3 neighbourhood of detected corners,
which follows the lens's curvature over a square without needing a camera model.
"""

from __future__ import annotations

import cv2
import numpy as np

# OpenCV's detectors in the order tried: the sector-based one is the more robust, the classic one finds
# some boards it misses; image normalisation rescues overexposed views, and costs detections elsewhere.
_DETECTORS = (
    ("sb", cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY),
    ("classic", cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE),
    ("sb", cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_NORMALIZE_IMAGE),
    ("classic", cv2.CALIB_CB_ADAPTIVE_THRESH),
)
HALF_WINDOW = 0.6  # half width of the symmetry window, in squares: inside the four squares around a corner
# Share of a patch's contrast that the symmetry leaves unexplained: 0.001-0.27 at real corners (median and
# 99th percentile over the real sets), about 1 for image noise alone.
MAX_ASYMMETRY = 0.5
MAX_SHIFT = 0.35  # squares; a fit that wanders further has left the corner (square centres are symmetric too)
_ITERATIONS = 10
_PASSES = 2  # the second pass fits the local grids to the refined corners
_SMOOTH_PX = 0.7  # pre-smoothing, so that bilinear sampling and central differences see a smooth image


def detect_corners(image: np.ndarray, board=(9, 6)) -> np.ndarray | None:
    """Inner corners (nx * ny, 2) in the order of `board_points`, or None when the board is not found.

    Either detector may start the grid at another corner; every such order is a symmetry of the grid,
    i.e. the same board under another rigid pose, so calibration is unaffected.
    """
    gray = to_gray8(image)
    corners = find_grid(gray, board)
    if corners is None:
        return None
    if min(board) < 3:  # too few neighbours for a local grid: OpenCV's gradient refinement
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
        refined = cv2.cornerSubPix(gray, corners.astype(np.float32).reshape(-1, 1, 2), (3, 3), (-1, -1), criteria)
        return refined.reshape(-1, 2).astype(float)
    return refine_corners(gray, corners, board)[0]


def find_grid(gray: np.ndarray, board) -> np.ndarray | None:
    """The detectors' corners (nx * ny, 2), unrefined, or None."""
    for kind, flags in _DETECTORS:
        if kind == "sb":
            ok, corners = cv2.findChessboardCornersSB(gray, board, flags=flags)
        else:
            ok, corners = cv2.findChessboardCorners(gray, board, flags=flags)
        if ok:
            return corners.reshape(-1, 2).astype(float)
    return None


def refine_corners(image: np.ndarray, corners: np.ndarray, board, half: float = HALF_WINDOW,
                   passes: int = _PASSES) -> tuple[np.ndarray, np.ndarray]:
    """Corners (N, 2) placed at the centre of point symmetry of the board image around each; and a mask of
    the corners whose fit converged (the others keep their input position).

    Gauss-Newton on the board-coordinate offset q of each corner, all corners at once: residuals
    I(m(q + d)) - I(m(q - d)) - 2 g.d over a Gaussian-weighted half window of offsets d, where m is the
    corner's local grid and g a linear illumination gradient across the corner (odd in d, so it would
    otherwise pull the corner towards the darker side).
    """
    img = cv2.GaussianBlur(to_gray8(image).astype(np.float32), (0, 0), _SMOOTH_PX)
    grad = [cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=1, scale=0.5), cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)]
    start = np.asarray(corners, float).reshape(-1, 2)
    out, ok = start.copy(), np.ones(len(start), bool)
    for _ in range(passes):
        coef = local_grids(out, board)
        offsets, weights = _window(coef, half)
        q = np.zeros((len(start), 2))
        for _ in range(_ITERATIONS):
            step, posed, _ = _gauss_newton_step(img, grad, coef, q, offsets, weights)
            q += np.clip(step, -0.2, 0.2)
            if np.abs(step).max() < 1e-3:
                break
        ok = posed & np.all(np.abs(q) <= MAX_SHIFT, axis=1) & np.all(np.isfinite(q), axis=1)
        moved = grid_map(coef, q[:, None])[0][:, 0]
        out = np.where(ok[:, None], moved, start)
    return out, ok


def local_grids(corners: np.ndarray, board) -> np.ndarray:
    """(N, 6, 2) coefficients of each corner's quadratic map from board offsets (s, t), in squares, to pixels,
    least-squares fitted to the 3x3 block of corners around it (moved inwards at the board's edge)."""
    nx, ny = board
    grid = np.asarray(corners, float).reshape(ny, nx, 2)
    j, i = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    dj, di = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    bi = np.clip(i - 1, 0, nx - 3)[..., None] + di.ravel()
    bj = np.clip(j - 1, 0, ny - 3)[..., None] + dj.ravel()
    A = _basis((bi - i[..., None]).astype(float), (bj - j[..., None]).astype(float))  # (ny, nx, 9, 6)
    At = np.swapaxes(A, -1, -2)
    coef = np.linalg.solve(At @ A, At @ grid[bj, bi])
    return coef.reshape(-1, 6, 2)


def grid_map(coef: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, K, 2) of board offsets q (N, K, 2) under each corner's grid, and d pixels / d q (N, K, 2, 2)."""
    s, t = q[..., 0], q[..., 1]
    uv = _basis(s, t) @ coef
    zero, one = np.zeros_like(s), np.ones_like(s)
    ds = np.stack([zero, one, zero, 2 * s, t, zero], axis=-1) @ coef
    dt = np.stack([zero, zero, one, zero, s, 2 * t], axis=-1) @ coef
    return uv, np.stack([ds, dt], axis=-1)


def _basis(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.stack([np.ones_like(s), s, t, s * s, s * t, t * t], axis=-1)


def _window(coef: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    """Half of a symmetric grid of offsets (d and -d are one residual) about a pixel apart on the median
    square, and their Gaussian weights."""
    square_px = float(np.median(np.linalg.norm(coef[:, 1:3], axis=-1)))
    n = int(np.clip(2 * half * square_px, 9, 41)) | 1
    s = np.linspace(-half, half, n)
    d = np.stack(np.meshgrid(s, s), axis=-1).reshape(-1, 2)
    d = d[(d[:, 1] > 0) | ((d[:, 1] == 0) & (d[:, 0] > 0))]
    return d, np.exp(-0.5 * np.sum(d * d, axis=1) / (0.5 * half) ** 2)


def _gauss_newton_step(img, grad, coef, q, offsets, weights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps (N, 2) in squares; whether each corner is placed (its position fixed in both directions, as a
    flat patch or a lone edge does not, and the patch symmetric enough to be a corner); the asymmetry."""
    def sample(a, uv):
        return cv2.remap(a, uv[..., 0].astype(np.float32), uv[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)

    terms = []
    for sign in (1.0, -1.0):
        uv, D = grid_map(coef, q[:, None] + sign * offsets)
        g = np.stack([sample(grad[0], uv), sample(grad[1], uv)], axis=-1)
        terms.append((sample(img, uv), g[..., :1] * D[..., 0, :] + g[..., 1:] * D[..., 1, :]))
    r = terms[0][0] - terms[1][0]
    J = np.concatenate([terms[0][1] - terms[1][1], np.broadcast_to(-2.0 * offsets, r.shape + (2,))], axis=-1)
    Jw = J * weights[:, None]
    A = np.swapaxes(Jw, 1, 2) @ J  # (N, 4, 4)
    b = (np.swapaxes(Jw, 1, 2) @ r[..., None])[..., 0]
    scale = np.trace(A[:, :2, :2], axis1=1, axis2=2)[:, None, None] + 1e-12
    # the damping keeps a singular system (a uniform patch) from stepping anywhere
    step = -np.linalg.solve(A + 1e-9 * scale * np.eye(4), b[..., None])[..., 0]
    eig = np.linalg.eigvalsh(A[:, :2, :2])
    # Asymmetry: the residual's share of the patch's contrast, 0 for a perfect corner and about 1 for noise.
    both = np.concatenate([terms[0][0], terms[1][0]], axis=1)
    w2 = np.concatenate([weights, weights])
    mean = both @ w2 / w2.sum()
    spread = np.square(both - mean[:, None]) @ w2
    asymmetry = (np.square(r) @ weights) / (spread + 1e-9)
    return step[:, :2], (eig[:, 0] > 1e-4 * eig[:, 1] + 1e-9) & (asymmetry < MAX_ASYMMETRY), asymmetry


def to_gray8(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.dtype != np.uint8:
        img = cv2.normalize(img.astype(np.float32), None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img
