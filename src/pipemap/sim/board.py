"""Checkerboard calibration views rendered through any pipemap camera model (the `calibration` preset).

Board frame: inner corner (i, j) of a board with (nx, ny) inner corners lies at (i * square, j * square, 0),
row by row (OpenCV's order). The printed squares span one square beyond the inner corners, and a white
margin of one more square surrounds them. A pose maps board to camera: X_cam = R(rvec) X_board + tvec.
The simulator keeps its own board geometry so that ground truth never depends on the calibration code.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from pipemap.camera import CameraModel, save_camera
from pipemap.camera.pinhole import PinholeCamera
from pipemap.errors import PipemapError
from pipemap.geometry.rotations import exp_so3, log_so3

BLACK, WHITE, BACKGROUND, OUTSIDE_FOV = 25.0, 225.0, 128.0, 0.0


class BoardView(NamedTuple):
    image: np.ndarray  # (height, width) uint8
    rvec: np.ndarray  # board-to-camera rotation vector
    tvec: np.ndarray  # board origin in the camera frame, metres


def inner_corners(board=(9, 6), square: float = 0.025) -> np.ndarray:
    """(nx * ny, 3) inner-corner positions on z = 0, row by row."""
    nx, ny = board
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    return np.stack([i.ravel() * square, j.ravel() * square, np.zeros(nx * ny)], axis=-1)


def _outline(board, square, per_edge: int = 24) -> np.ndarray:
    """Points along the outer edge of the white margin, where visibility is decided."""
    nx, ny = board
    x0, x1, y0, y1 = -2 * square, (nx + 1) * square, -2 * square, (ny + 1) * square
    s = np.linspace(0.0, 1.0, per_edge, endpoint=False)
    xs, ys = x0 + s * (x1 - x0), y0 + s * (y1 - y0)
    edges = [np.stack([xs, np.full_like(s, y0)], -1), np.stack([np.full_like(s, x1), ys], -1),
             np.stack([xs[::-1] + (x1 - x0) / per_edge, np.full_like(s, y1)], -1),
             np.stack([np.full_like(s, x0), ys[::-1] + (y1 - y0) / per_edge], -1)]
    pts = np.concatenate(edges)
    return np.concatenate([pts, np.zeros((len(pts), 1))], axis=-1)


def _focal_px(camera: CameraModel) -> float:
    """Pixels per radian near the optical axis."""
    uv, _ = camera.project(np.array([[0.0, 0.0, 1.0], [1e-3, 0.0, 1.0]]))
    return float(np.hypot(*(uv[1] - uv[0])) / 1e-3)


def _perpendicular(v: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    a = rng.normal(size=3)
    a -= a.dot(v) * v
    return a / np.linalg.norm(a)


def random_board_poses(camera: CameraModel, board=(9, 6), square: float = 0.025, n_views: int = 20,
                       rng: np.random.Generator | int = 0, max_tilt_deg: float = 50.0,
                       min_square_px: float = 9.0, max_tries: int = 400) -> list[tuple[np.ndarray, np.ndarray]]:
    """Board poses (rvec, tvec) that keep the whole board, margin included, inside the image.

    Board centres are spread uniformly over the disc of the field of view, so a fisheye sees the board
    out to its periphery (corners up to ~85-90 deg), at tilts up to `max_tilt_deg` from facing the camera.
    """
    rng = np.random.default_rng(rng)
    nx, ny = board
    centre = np.array([(nx - 1) * square / 2, (ny - 1) * square / 2, 0.0])
    corners, outline = inner_corners(board, square), _outline(board, square)
    diag = np.hypot(nx + 3, ny + 3) * square
    fisheye = not isinstance(camera, PinholeCamera)
    theta_hi = min(camera.max_theta, np.radians(95)) * (0.8 if fisheye else 0.75)
    # Angular size of the board: large enough for the detector near the centre, small enough to fit.
    f = _focal_px(camera)
    min_extent = min_square_px * diag / square / f
    max_extent = 0.9 * (2 * theta_hi if fisheye else 2 * np.arctan(0.5 * min(camera.width, camera.height) / f))
    poses: list[tuple[np.ndarray, np.ndarray]] = []
    for _ in range(max_tries * n_views):
        if len(poses) == n_views:
            break
        theta = theta_hi * np.sqrt(rng.uniform())
        phi = rng.uniform(0, 2 * np.pi)
        ray = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        extent = rng.uniform(min_extent, max(min_extent, max_extent))
        distance = diag / (2 * np.tan(min(extent, 2.6) / 2))
        tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform())
        z_b = exp_so3(tilt * _perpendicular(ray, rng)) @ ray
        x_b = _perpendicular(z_b, rng)
        R = np.stack([x_b, np.cross(z_b, x_b), z_b], axis=-1)
        t = distance * ray - R @ centre
        if _visible(camera, R, t, corners, outline, min_square_px, board):
            poses.append((log_so3(R), t))
    if len(poses) < n_views:
        raise PipemapError(f"could place only {len(poses)} of {n_views} board views inside the image "
                           f"(board {nx}x{ny}, square {square} m, camera {camera.width}x{camera.height})")
    return poses


def _visible(camera, R, t, corners, outline, min_square_px, board) -> bool:
    Xo = outline @ R.T + t
    Xc = corners @ R.T + t
    _, ok_outline = camera.project(Xo)
    uv, ok = camera.project(Xc)
    if not (ok_outline.all() and ok.all()):
        return False
    inside = (uv[:, 0] > 3) & (uv[:, 0] < camera.width - 4) & (uv[:, 1] > 3) & (uv[:, 1] < camera.height - 4)
    if not inside.all():
        return False
    # Grazing views and tiny squares defeat any corner detector.
    normal = R[:, 2]
    cos_incidence = np.abs(Xc @ normal) / np.linalg.norm(Xc, axis=-1)
    if cos_incidence.min() < np.cos(np.radians(75)):
        return False
    nx, ny = board
    grid = uv.reshape(ny, nx, 2)
    step = min(np.linalg.norm(np.diff(grid, axis=0), axis=-1).min(),
               np.linalg.norm(np.diff(grid, axis=1), axis=-1).min())
    return bool(step >= min_square_px)


def _board_shade(xb: np.ndarray, yb: np.ndarray, board, square) -> np.ndarray:
    nx, ny = board
    i, j = np.floor(xb / square), np.floor(yb / square)
    squares = (i >= -1) & (i < nx) & (j >= -1) & (j < ny)
    on_board = (xb >= -2 * square) & (xb < (nx + 1) * square) & (yb >= -2 * square) & (yb < (ny + 1) * square)
    dark = squares & ((i + j) % 2 == 0)
    return np.where(on_board, np.where(dark, BLACK, WHITE), BACKGROUND)


def _ray_grid(camera: CameraModel, s: int) -> tuple[np.ndarray, np.ndarray]:
    """(height*s, width*s) float32 bearings of s x s sub-pixel samples per pixel; the same for every view."""
    off = (np.arange(s) + 0.5) / s - 0.5
    us = (np.arange(camera.width)[:, None] + off).ravel()
    vs = (np.arange(camera.height)[:, None] + off).ravel()
    bearings = np.empty((vs.size, us.size, 3), np.float32)
    valid = np.empty((vs.size, us.size), bool)
    for start in range(0, vs.size, 128):  # bounds the float64 temporaries on large images
        grid = np.stack(np.meshgrid(us, vs[start:start + 128]), axis=-1)
        bearings[start:start + 128], valid[start:start + 128] = camera.unproject(grid)
    return bearings, valid


def _board_box(camera: CameraModel, R, t, board, square) -> tuple[int, int, int, int]:
    """Pixel rows and columns [r0, r1) x [c0, c1) that contain the board's image (its outline bounds it)."""
    uv, _ = camera.project(_outline(board, square, per_edge=64) @ R.T + t)
    c0, r0 = np.floor(uv.min(axis=0)).astype(int) - 2
    c1, r1 = np.ceil(uv.max(axis=0)).astype(int) + 3
    return max(r0, 0), min(r1, camera.height), max(c0, 0), min(c1, camera.width)


def render_board_views(camera: CameraModel, board=(9, 6), square: float = 0.025, n_views: int = 20, seed: int = 0,
                       noise_sigma: float = 2.0, supersample: int = 2, poses=None) -> list[BoardView]:
    """Render checkerboard views; each pixel averages supersample x supersample rays cast onto the board plane.

    `poses` (a list of (rvec, tvec)) replaces the random placement; the noise still follows `seed`.
    """
    rng = np.random.default_rng(seed)
    if poses is None:
        poses = random_board_poses(camera, board, square, n_views, rng)
    s = int(supersample)
    bearings, valid = _ray_grid(camera, s)
    empty = np.where(valid, BACKGROUND, OUTSIDE_FOV).reshape(camera.height, s, camera.width, s).mean(axis=(1, 3))
    views = []
    for rvec, tvec in poses:
        R = exp_so3(np.asarray(rvec, float))
        t = np.asarray(tvec, float)
        r0, r1, c0, c1 = _board_box(camera, R, t, board, square)
        rays = bearings[r0 * s:r1 * s, c0 * s:c1 * s]
        normal = R[:, 2].astype(np.float32)
        denom = rays @ normal
        depth = np.float32(normal @ t) / np.where(np.abs(denom) < 1e-9, np.float32(1e-9), denom)
        local = (depth[..., None] * rays - t.astype(np.float32)) @ R[:, :2].astype(np.float32)
        shade = _board_shade(local[..., 0], local[..., 1], board, square)
        shade = np.where(depth > 0, shade, BACKGROUND)
        shade = np.where(valid[r0 * s:r1 * s, c0 * s:c1 * s], shade, OUTSIDE_FOV)
        img = empty.copy()
        img[r0:r1, c0:c1] = shade.reshape(r1 - r0, s, c1 - c0, s).mean(axis=(1, 3))
        img = img + rng.normal(0.0, noise_sigma, img.shape)
        views.append(BoardView(np.clip(np.rint(img), 0, 255).astype(np.uint8), np.asarray(rvec, float), t))
    return views


def save_board_views(out_dir: str | Path, camera: CameraModel, board=(9, 6), square: float = 0.025, n_views: int = 20,
                     seed: int = 0, noise_sigma: float = 2.0, **kwargs) -> list[Path]:
    """Write images/000000.png ... and camera.yaml (the true camera, board and poses); returns the image paths."""
    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    views = render_board_views(camera, board, square, n_views, seed, noise_sigma, **kwargs)
    paths, records = [], []
    for k, view in enumerate(views):
        path = out / "images" / f"{k:06d}.png"
        if not cv2.imwrite(str(path), view.image):
            raise PipemapError("cannot write image", path)
        paths.append(path)
        records.append({"image": f"images/{path.name}", "rvec": [float(x) for x in view.rvec],
                        "tvec": [float(x) for x in view.tvec]})
    truth = {"board": f"{board[0]}x{board[1]}", "square_m": float(square), "seed": int(seed),
             "noise_sigma": float(noise_sigma), "poses": records}
    save_camera(out / "camera.yaml", camera, extra={"calibration_truth": truth})
    return paths
