"""Reduce and undistort perspective frames (2010 report section 4.2: quarter resolution, distortion removed).

The frame is first reduced with area averaging (no aliasing), then undistorted at the reduced size
with a map built once by cv2.initUndistortRectifyMap. The rectified view keeps the reduced
camera's focal length and principal point, so one pixel of motion at the image centre means the
same wall distance everywhere in a run.
"""

from __future__ import annotations

import cv2
import numpy as np

from pipemap.camera import CameraModel
from pipemap.camera.pinhole import PinholeCamera
from pipemap.errors import PipemapError


class Rectifier:
    """Maps a full-size frame to the reduced, undistorted perspective view.

    `K` is the rectified view's intrinsic matrix, `size` its (width, height) and `valid` the mask of
    rectified pixels that come from inside the source image.
    """

    def __init__(self, camera: CameraModel, scale: float, where=None):
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
        self.K = np.array([[fx * sx, 0, (cx + 0.5) * sx - 0.5], [0, fy * sy, (cy + 0.5) * sy - 0.5], [0, 0, 1.0]])
        self.dist = np.array([k1, k2, p1, p2, k3])
        self.size = (w, h)
        self.scale = scale
        self.source_size = (camera.width, camera.height)
        self._map1, self._map2 = cv2.initUndistortRectifyMap(self.K, self.dist, None, self.K, self.size, cv2.CV_32FC1)
        inside = (self._map1 >= 0) & (self._map1 <= w - 1) & (self._map2 >= 0) & (self._map2 <= h - 1)
        self.valid = inside

    @property
    def focal_px(self) -> float:
        return float(self.K[0, 0])

    def __call__(self, image: np.ndarray) -> np.ndarray:
        img = np.asarray(image, np.float32)
        if img.shape[:2] != self.source_size[::-1]:
            raise PipemapError(f"frame is {img.shape[1]}x{img.shape[0]}, the camera is "
                               f"{self.source_size[0]}x{self.source_size[1]}")
        if self.size != self.source_size:
            img = cv2.resize(img, self.size, interpolation=cv2.INTER_AREA)
        return cv2.remap(img, self._map1, self._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
