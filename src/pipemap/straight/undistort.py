"""Reduce and undistort perspective frames (2010 report section 4.2: quarter resolution, distortion removed).

The frame is first reduced with area averaging (no aliasing), then undistorted at the reduced size
with a map built once by cv2.initUndistortRectifyMap. The rectified view keeps the reduced
camera's focal length, so one pixel of motion at the image centre means the same wall distance
everywhere in a run.

The dense methods' translation model holds for a camera square to the wall with image x along the
pipe (report section 4.2). Given the camera's mount (its rotation in the pipe frame, mount.py), the
view is turned to a virtual camera in that pose at the same centre: the report's R0, optical axis
square to the wall in the direction the camera looks, image x along the axis. Its window is the part
of the virtual image the real (undistorted) image covers: along the pipe the central row's extent,
cut where the view gets more oblique than `max_angle_deg` from square (there one pixel of the oblique
camera spreads over several rectified ones); across it the rows every column of that extent sees. Its
focal length is the reduced camera's, raised where the turn compresses the near wall so that no part
of it is sampled more coarsely than the reduced image. For a camera square to the wall the window is
the undistorted image itself.

On a curved wall the rows of that view move apart: a row that sees the wall at depth z(v) moves by
f dh / z(v) when the camera moves dh along the axis (7 % between the band's edges for a camera 4 cm off
the axis of a 388 mm pipe), so a single image translation fits no row exactly, and what it measures
depends on where the texture is. Given the wall's depth per row (`row_depth`, from the radius and the
camera's offset, scale.py), every row is resampled along x by z(v) / z_ref (z_ref: the middle row's),
so that an axial move shifts every row by the same f dh / z_ref; `row_gain` is that factor per row and
the window is cut to the columns every row then has.
"""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from pipemap.camera import CameraModel
from pipemap.camera.pinhole import PinholeCamera
from pipemap.errors import PipemapError
from pipemap.straight.sparse.geometry import R0


class Rectifier:
    """Maps a full-size frame to the reduced, undistorted perspective view.

    `K` is the rectified view's intrinsic matrix, `size` its (width, height) and `valid` the mask of
    rectified pixels that come from inside the source image.
    """

    def __init__(self, camera: CameraModel, scale: float, where=None, mount: np.ndarray | None = None,
                 max_angle_deg: float = 60.0, row_depth: Callable[[np.ndarray], np.ndarray] | None = None):
        if not isinstance(camera, PinholeCamera):
            raise PipemapError(
                f"dense VO needs a perspective (pinhole) camera looking at the wall; the {camera.model} camera is a "
                "fisheye model, which the 2010 report's dense method does not handle (use the fisheye pipeline)",
                where, "camera.model")
        if not 0 < scale <= 1:
            raise PipemapError(f"image reduction must be in (0, 1], got {scale}", where, "dense.scale")
        fx, fy, cx, cy, k1, k2, p1, p2, k3 = (float(v) for v in camera.params)
        w, h = max(16, int(round(camera.width * scale))), max(16, int(round(camera.height * scale)))
        sx, sy = w / camera.width, h / camera.height
        # pixel centres: u_small = (u + 0.5) * s - 0.5
        K = np.array([[fx * sx, 0, (cx + 0.5) * sx - 0.5], [0, fy * sy, (cy + 0.5) * sy - 0.5], [0, 0, 1.0]])
        self.dist = np.array([k1, k2, p1, p2, k3])
        self.scale = scale
        self.source_size = (camera.width, camera.height)
        # camera axes -> the virtual camera's (R0^T R: through the pipe frame); identity without a mount
        self.rotation = np.eye(3) if mount is None else R0.T @ np.asarray(mount, float)
        self.K, self.size, self.reduced_size = K, (w, h), (w, h)
        if mount is not None:
            self.K, self.size = square_window(K, (w, h), self.rotation, max_angle_deg, where)
        self._map1, self._map2 = cv2.initUndistortRectifyMap(K, self.dist, self.rotation, self.K, self.size,
                                                             cv2.CV_32FC1)
        self.row_gain = np.ones(self.size[1])  # virtual-view pixels per resampled pixel along x, per row
        if row_depth is not None:
            self._equalise_rows(row_depth, where)
        self.valid = (self._map1 >= 0) & (self._map1 <= w - 1) & (self._map2 >= 0) & (self._map2 <= h - 1)

    def _equalise_rows(self, row_depth: Callable[[np.ndarray], np.ndarray], where) -> None:
        """Resample each row along x by its wall depth over the middle row's (module docstring)."""
        w, h = self.size
        cx, cy = self.K[0, 2], self.K[1, 2]
        depth = np.asarray(row_depth((np.arange(h) - cy) / self.K[1, 1]), float)
        ref = float(np.asarray(row_depth(np.array([((h - 1) / 2 - cy) / self.K[1, 1]])), float)[0])
        if not (np.all(np.isfinite(depth)) and np.all(depth > 0) and ref > 0):
            raise PipemapError("the wall's depth is undefined on some rows of the view turned square to it", where,
                               "camera_offset_m")
        gain = ref / depth  # virtual x = cx + (x' - cx) * gain: the near rows spread, the far ones shrink
        g = float(gain.max())
        lo, hi = cx - cx / g, cx + (w - 1 - cx) / g  # the columns x' every row has
        width = int(np.floor(hi - lo + 1e-9)) + 1
        if width < 16:
            raise PipemapError(f"the view with its rows resampled to the wall is {width} px wide; too small to "
                               "register", where, "dense.scale")
        x = cx + (lo + np.arange(width)[None, :] - cx) * gain[:, None]
        i0 = np.clip(np.floor(x).astype(int), 0, w - 2)
        t = (x - i0).astype(np.float32)
        maps = [np.take_along_axis(m, i0, 1) * (1 - t) + np.take_along_axis(m, i0 + 1, 1) * t
                for m in (self._map1, self._map2)]
        self._map1, self._map2 = (np.ascontiguousarray(m, np.float32) for m in maps)
        self.K = self.K.copy()
        self.K[0, 2] = cx - lo
        self.size = (width, h)
        self.row_gain = gain

    @property
    def maps(self) -> tuple[np.ndarray, np.ndarray]:
        """Where each pixel of the view is sampled in the reduced frame: (x, y), each (height, width)."""
        return self._map1, self._map2

    @property
    def focal_px(self) -> float:
        return float(self.K[0, 0])

    def __call__(self, image: np.ndarray) -> np.ndarray:
        img = np.asarray(image, np.float32)
        if img.shape[:2] != self.source_size[::-1]:
            raise PipemapError(f"frame is {img.shape[1]}x{img.shape[0]}, the camera is "
                               f"{self.source_size[0]}x{self.source_size[1]}")
        if self.reduced_size != self.source_size:
            img = cv2.resize(img, self.reduced_size, interpolation=cv2.INTER_AREA)
        return cv2.remap(img, self._map1, self._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def square_window(K: np.ndarray, size: tuple[int, int], rotation: np.ndarray, max_angle_deg: float,
                  where=None) -> tuple[np.ndarray, tuple[int, int]]:
    """Intrinsics and size of the virtual camera's window (module docstring): the extent along x of the ideal
    image's central row turned by `rotation` (camera -> virtual axes) and cut at max_angle_deg, the rows that the
    turned image covers over all of that extent, at K's focal length or above."""
    w, h = size
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    t = np.linspace(0.0, 1.0, 257)

    def turned(u, v):  # pixels of the ideal image -> normalised virtual coordinates, and whether in front
        rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1) @ rotation.T
        front = rays[:, 2] > 1e-6
        return rays[:, :2] / np.where(front, rays[:, 2], 1.0)[:, None], front

    row, ok = turned(t * (w - 1), np.full_like(t, cy))
    limit = np.tan(np.radians(max_angle_deg))
    x = row[ok, 0]
    x = x[np.abs(x) <= limit]
    if x.size < 2:
        raise PipemapError(f"the camera looks more than {max_angle_deg:g} deg away from square to the wall; the dense "
                           "methods cannot turn its view square to it", where, "dense.rectify_max_angle_deg")
    x_lo, x_hi = float(x.min()), float(x.max())
    # the focal length at which no part of the window is sampled more coarsely than the reduced image: where the
    # turn compresses the wall (the near side of an oblique view), the same focal length would alias its texture
    inside = ok & (np.abs(row[:, 0]) <= limit)
    both = inside[1:] & inside[:-1]
    gain = np.diff(t * (w - 1))[both] / (fx * np.diff(row[:, 0])[both])  # source pixels per virtual pixel at fx
    f = fx * max(1.0, float(np.max(np.abs(gain)))) if gain.size else fx
    top, ok_t = turned(t * (w - 1), np.zeros_like(t))
    bottom, ok_b = turned(t * (w - 1), np.full_like(t, h - 1.0))
    # the turned edges are straight lines: their rows over [x_lo, x_hi] from a fit, the inner one of each end
    y_top = max(np.polyval(np.polyfit(top[ok_t, 0], top[ok_t, 1], 1), [x_lo, x_hi]))
    y_bottom = min(np.polyval(np.polyfit(bottom[ok_b, 0], bottom[ok_b, 1], 1), [x_lo, x_hi]))
    width = int(np.floor(f * (x_hi - x_lo) + 1e-6)) + 1
    height = int(np.floor(f * (y_bottom - y_top) + 1e-6)) + 1
    if width < 16 or height < 16:
        raise PipemapError(f"the view turned square to the wall is {width}x{height} px; too small to register",
                           where, "dense.scale")
    Kv = np.array([[f, 0.0, -f * x_lo], [0.0, f, -f * y_top], [0.0, 0.0, 1.0]])
    return Kv, (width, height)


QUARTER = 0.25  # the report's reduction (section 4.2: 256x192 and 160x120)


def reduction_for_wall(camera: CameraModel, distance_m: float, wall_mm_per_px: float) -> float:
    """The report's quarter resolution, or less reduced where a quarter-resolution pixel at the principal point
    would cover more than wall_mm_per_px of a wall `distance_m` away: the report's reductions sampled its walls at
    0.55 (6-inch) and 0.73 mm (16-inch) per pixel; a 70 deg, 640 px camera 0.23 m from the wall samples it at 1.9 mm
    at a quarter, where the registration of the simulator's wall falls 0.5-0.8 % short and at 1 mm does not."""
    focal = float(np.mean(camera.params[:2]))
    mm_per_px = 1e3 * distance_m / (focal * QUARTER)
    return float(min(1.0, QUARTER * max(1.0, mm_per_px / wall_mm_per_px)))
