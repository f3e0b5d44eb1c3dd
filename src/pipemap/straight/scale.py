"""zeta, pixels per metre (2010 report section 3.3, eqs. 18-19).

The report measured zeta with a calibration target fixed to the wall. Without one, pipemap
computes it from the rectified camera, the pipe radius and the camera's position in the pipe,
assuming (as the report does) that the principal axis is perpendicular to the pipe axis and
image x runs along the pipe:

- camera frame: x along the pipe, z the principal axis towards the wall;
- `offset_m` is the camera's displacement from the pipe axis along its principal axis (positive
  towards the wall it looks at, negative away: a camera below the axis looking up has a
  negative offset); the wall on the principal axis is then at d = r - offset_m; `side_m` is its
  displacement along image y (the report's C_X for its R0; 0 unless the mount was estimated);
- a pixel row v sees the wall at the depth z(v) where its ray (0, v', 1) (v' = (v - cy) / f)
  meets the circle of radius r around (-side_m, -offset_m) in the camera's y-z plane; the wall does
  not curve along x, so an axial move dh shifts row v by f dh / z(v);
- zeta is the mean of f / z(v) over the rows the registration compares (the report's "mean
  pixel per metre" over its target), so the curvature of the wall inside the band is accounted
  for to first order. At the principal point it is f / (r - offset_m);
- rows do not count alike in a registration: a uniform shift fitted to rows that move by
  different amounts is their mean weighted by each row's texture (its squared x-gradients, the
  weights of the Lucas-Kanade normal equations), so the dense methods weigh `row_pixels_per_metre`
  the same way, pair by pair (a texture concentrated on the near rows would read as faster motion).
"""

from __future__ import annotations

import numpy as np

from pipemap.errors import PipemapError


def wall_depth(v_norm: np.ndarray, radius_m: float, offset_m: float, side_m: float = 0.0) -> np.ndarray:
    """Depth along the principal axis of the wall seen by normalised row coordinates v' = (v - cy) / f."""
    v = np.asarray(v_norm, float)
    a = 1 + v * v
    b = 2 * (offset_m + side_m * v)
    c = offset_m**2 + side_m**2 - radius_m**2
    lam = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)
    return lam


def row_pixels_per_metre(focal_px: float, cy: float, radius_m: float, offset_m: float = 0.0, rows=None,
                         side_m: float = 0.0) -> np.ndarray:
    """f / z(v) of each pixel row in [rows[0], rows[1]) (just the principal point's when rows is None)."""
    if not radius_m > 0:
        raise PipemapError(f"the pipe radius must be positive, got {radius_m}", key="pipe.radius_m")
    if not np.hypot(offset_m, side_m) < radius_m:
        raise PipemapError(f"the camera offset {np.hypot(offset_m, side_m):g} m puts the camera outside the pipe of "
                           f"radius {radius_m} m", key="camera_offset_m")
    v = np.zeros(1) if rows is None else (np.arange(int(rows[0]), int(rows[1])) - cy) / focal_px
    return focal_px / wall_depth(v, radius_m, offset_m, side_m)


def pixels_per_metre(focal_px: float, cy: float, radius_m: float, offset_m: float = 0.0, rows=None,
                     side_m: float = 0.0) -> float:
    """zeta: mean f / z(v) over the pixel rows [rows[0], rows[1]) (just the principal point when rows is None)."""
    return float(np.mean(row_pixels_per_metre(focal_px, cy, radius_m, offset_m, rows, side_m)))
