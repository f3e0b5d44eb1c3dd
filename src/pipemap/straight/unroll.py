"""Unrolled wall images of a straight pipe (2010 report section 6.1, Figs. 15 and 17).

The wall is a grid in wall coordinates (h along the axis, rho = r phi around it; the pipe frame
and phi convention of pipemap.straight.sparse.geometry). Each image's gain-corrected pixels are
carried onto the grid by its pose and the cylinder: every grid cell's wall point is projected
into the image with the calibrated camera (distortion included) and sampled with cv2.remap; the
unrolled value is the mean over the images that see the cell (the report's simple stitching,
which makes pose errors show as doubled or smeared texture).

Grid: column j is h = h0 + j * mpp, row i is rho = rho0 + i * mpp. Rows grow with rho, i.e.
clockwise seen looking along +h: the image shows the wall as seen from outside the pipe (a mirror
image of the camera's own view, where wall markings read the right way round).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

import cv2
import numpy as np

from pipemap.camera import CameraModel
from pipemap.errors import PipemapError
from pipemap.straight.sparse.geometry import wall_coords, wall_from_coords, wall_points


@dataclass(frozen=True)
class UnrolledWall:
    image: np.ndarray  # (rows, cols) float32 mean grey level, NaN where no image saw the wall
    count: np.ndarray  # (rows, cols) images contributing to each cell
    h0: float  # h of pixel (0, 0)
    rho0: float  # rho of pixel (0, 0)
    metres_per_pixel: float


def footprint(camera: CameraModel, R: np.ndarray, C: np.ndarray, radius: float, samples: int = 16) -> np.ndarray:
    """(h_min, h_max, rho_min, rho_max) of the wall seen through the image border of pose (R, C)."""
    w, h = camera.width - 1, camera.height - 1
    t = np.linspace(0.0, 1.0, samples)
    border = np.concatenate([np.stack([t * w, 0 * t], -1), np.stack([t * w, h + 0 * t], -1),
                             np.stack([0 * t, t * h], -1), np.stack([w + 0 * t, t * h], -1)])
    bearings, _ = camera.unproject(border)
    X, valid = wall_points(R, C, bearings, radius)
    if not valid.any():
        return np.array([C[2], C[2], 0.0, 0.0])
    hr = wall_coords(X[valid], radius)
    return np.array([hr[:, 0].min(), hr[:, 0].max(), hr[:, 1].min(), hr[:, 1].max()])


def centre_footprint_m(camera: CameraModel, R: np.ndarray, C: np.ndarray, radius: float) -> float:
    """Wall size of one pixel at the principal point of pose (R, C): range / focal length."""
    cx, cy = camera.params[2], camera.params[3]
    b, _ = camera.unproject(np.array([[cx, cy], [cx + 1.0, cy]]))
    X, _ = wall_points(R, C, b, radius)
    return float(np.linalg.norm(X[1] - X[0]))


def unroll(views: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], camera: CameraModel, radius: float,
           bounds: np.ndarray, metres_per_pixel: float) -> UnrolledWall:
    """Mean of the images (image, R, C) carried onto the wall grid covering `bounds`
    (h_min, h_max, rho_min, rho_max) at `metres_per_pixel`."""
    mpp = float(metres_per_pixel)
    if not mpp > 0:
        raise PipemapError(f"unrolled pixel size must be positive, got {mpp}", key="sparse.unrolled_px_m")
    h0, rho0 = float(np.floor(bounds[0] / mpp) * mpp), float(np.floor(bounds[2] / mpp) * mpp)
    cols = int(np.ceil((bounds[1] - h0) / mpp)) + 1
    rows = int(np.ceil((bounds[3] - rho0) / mpp)) + 1
    acc = np.zeros((rows, cols), np.float32)
    cnt = np.zeros((rows, cols), np.float32)
    for image, R, C in views:
        h_lo, h_hi, r_lo, r_hi = footprint(camera, R, C, radius)
        j0, j1 = max(0, int((h_lo - h0) / mpp) - 1), min(cols, int(np.ceil((h_hi - h0) / mpp)) + 2)
        i0, i1 = max(0, int((r_lo - rho0) / mpp) - 1), min(rows, int(np.ceil((r_hi - rho0) / mpp)) + 2)
        if j1 <= j0 or i1 <= i0:
            continue
        hh, rr = np.meshgrid(h0 + mpp * np.arange(j0, j1), rho0 + mpp * np.arange(i0, i1))
        X = wall_from_coords(np.stack([hh, rr], axis=-1), radius)
        uv, ok = camera.project((X - C) @ R)  # R^T (X - C) row by row
        map_u = np.where(ok, uv[..., 0], -10.0).astype(np.float32)
        map_v = np.where(ok, uv[..., 1], -10.0).astype(np.float32)
        tile = cv2.remap(np.asarray(image, np.float32), map_u, map_v, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)
        acc[i0:i1, j0:j1] += np.where(ok, tile, 0.0)
        cnt[i0:i1, j0:j1] += ok
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt > 0, acc / np.maximum(cnt, 1), np.nan).astype(np.float32)
    return UnrolledWall(mean, cnt.astype(np.int32), h0, rho0, mpp)


def frame_images(dataset, indices, gain_correct: bool) -> Iterator[np.ndarray]:
    """The images of the frames `indices` (ascending), as read for mapping."""
    wanted = set(int(i) for i in indices)
    if dataset.image_paths is not None:
        for i in indices:
            yield dataset.read(int(i), gain_correct=gain_correct).image
        return
    for frame in dataset.frames(gain_correct=gain_correct):  # a video: one pass, no seeking
        if frame.index in wanted:
            yield frame.image


def wall_sidecar(wall: UnrolledWall, radius: float, R_first: np.ndarray, C_first: np.ndarray) -> dict:
    """The common sidecar (mapping.unrolled_sidecar) of `wall` written with its rows flipped (seen from inside),
    in the world of a trajectory whose origin is the first camera, at (R_first, C_first) in the pipe frame:
    phi = 0 where the report's R0 camera looks (up), which is 12 o'clock for the report's robots."""
    from pipemap.mapping.unrolled import unrolled_sidecar

    rows, cols = wall.image.shape
    mpp = wall.metres_per_pixel

    def world(h: float) -> np.ndarray:  # the axis point at pipe-frame h, in the first camera's frame
        return (np.array([0.0, 0.0, h]) - C_first) @ R_first

    return unrolled_sidecar(
        "pipe", rows, cols, start=world(wall.h0), end=world(wall.h0 + (cols - 1) * mpp), radius=radius,
        up=np.array([0.0, 1.0, 0.0]) @ R_first, px_m=mpp, along_m=mpp,
        phi_of_row_0=(wall.rho0 + (rows - 1) * mpp) / radius, phi_per_row=-mpp / radius,
        seen_fraction=float(np.isfinite(wall.image).mean()),
        chainage_of_column_0=float(wall.h0 - C_first[2]))  # one piece: chainage from the first camera's place


def unroll_poses(images: Iterable[np.ndarray], camera: CameraModel, radius: float, R: np.ndarray, C: np.ndarray,
                 px_m: float | None, max_px: int) -> UnrolledWall:
    """The mean of `images` seen from poses R (K, 3, 3), C (K, 3) in the pipe frame, on a grid covering what they
    see at px_m metres per pixel (None: one camera pixel at the first pose's principal point), coarser where the
    longest side would exceed max_px."""
    bounds = np.array([footprint(camera, r, c, radius) for r, c in zip(R, C)])
    box = np.array([bounds[:, 0].min(), bounds[:, 1].max(), bounds[:, 2].min(), bounds[:, 3].max()])
    mpp = px_m or centre_footprint_m(camera, R[0], C[0], radius)
    mpp = max(mpp, max(box[1] - box[0], box[3] - box[2]) / (max_px - 1))
    return unroll(zip(images, R, C), camera, radius, box, mpp)


def write_wall(folder: Path, stem: str, wall: UnrolledWall, radius: float, R_first: np.ndarray, C_first: np.ndarray,
               **details) -> None:
    """<stem>.png (rows flipped: the wall seen from inside, as every method shows it) and <stem>.json, the
    common sidecar (wall_sidecar) with the method's `details`, into `folder`, which it creates."""
    import json

    from pipemap.output import atomic_write_bytes, atomic_write_text

    folder.mkdir()
    atomic_write_bytes(folder / f"{stem}.png", to_png(wall.image[::-1]))
    side = wall_sidecar(wall, radius, R_first, C_first)
    side.update(image=f"{stem}.png", **details)
    atomic_write_text(folder / f"{stem}.json", json.dumps(side, indent=2) + "\n")


def to_png(image: np.ndarray) -> bytes:
    """8-bit PNG of a float image: 0.5..99.5 percentile stretched to 1..255, 0 where NaN (unseen)."""
    ok = np.isfinite(image)
    lo, hi = (np.percentile(image[ok], [0.5, 99.5]) if ok.any() else (0.0, 1.0))
    out = np.zeros(image.shape, np.uint8)
    out[ok] = np.clip((image[ok] - lo) / max(hi - lo, 1e-6) * 254 + 1, 1, 255).astype(np.uint8)
    good, buf = cv2.imencode(".png", out)
    if not good:
        raise PipemapError("could not encode a wall image as PNG")
    return buf.tobytes()
