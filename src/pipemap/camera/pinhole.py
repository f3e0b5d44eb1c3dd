"""Perspective camera with OpenCV's radial-tangential distortion (the 2010 report's cameras)."""

from __future__ import annotations

import numpy as np

from pipemap.camera.base import CameraModel, _check_last_dim
from pipemap.errors import PipemapError

_NEWTON_STEPS = 20


class PinholeCamera(CameraModel):
    model = "pinhole"
    param_names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")

    def _validate(self):
        for i, name in enumerate(("fx", "fy")):
            if self.params[i] <= 0:
                raise PipemapError(f"focal length {name} must be positive, got {self.params[i]:g}",
                                   key=f"camera.params.{name}")

    def _radial(self, r2):
        k1, k2, k3 = self.params[4], self.params[5], self.params[8]
        return 1 + r2 * (k1 + r2 * (k2 + r2 * k3))

    def _resolve_max_theta(self, given_deg):
        fx, fy, cx, cy = self.params[:4]
        corners = np.array([[-0.5, -0.5], [self.width - 0.5, -0.5], [-0.5, self.height - 0.5],
                            [self.width - 0.5, self.height - 0.5]])
        reach = np.max(np.hypot((corners[:, 0] - cx) / fx, (corners[:, 1] - cy) / fy))
        # Tangential terms are small; monotonicity is judged on the radial part, as OpenCV does.
        r = np.linspace(0.0, max(4.0 * reach, 1.0), 40001)
        rd = r * self._radial(r * r)
        drd = np.diff(rd)
        turn = np.nonzero(drd <= 0)[0]
        limit_r = r[turn[0]] if turn.size else np.inf
        reach_idx = np.searchsorted(np.maximum.accumulate(rd), reach * (1 + 1e-6))
        if limit_r < np.inf and (reach_idx >= turn[0]):
            raise PipemapError(
                "the pinhole distortion is not monotone over the field of view "
                f"(distorted radius peaks at {rd[turn[0]]:.3f}, the image corners need {reach:.3f})",
                key="camera.params",
            )
        self._r_limit = float(limit_r)
        if given_deg is not None:
            if not 0 < given_deg < 90:
                raise PipemapError(f"max_theta_deg of a pinhole camera must be in (0, 90), got {given_deg}",
                                   key="camera.max_theta_deg")
            return float(np.radians(given_deg))
        return float(np.pi / 2)

    def _project(self, X, jacobians):
        fx, fy, cx, cy, k1, k2, p1, p2, k3 = self.params
        z = X[..., 2]
        zs = np.where(np.abs(z) < 1e-300, 1e-300, z)
        x = X[..., 0] / zs
        y = X[..., 1] / zs
        r2 = x * x + y * y
        rad = self._radial(r2)
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        uv = np.stack([fx * xd + cx, fy * yd + cy], axis=-1)
        if not jacobians:
            return uv, None, None
        drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d rad / d r2
        dxd_dx = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
        dxd_dy = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
        dyd_dx = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
        dyd_dy = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
        # d(x, y)/dX for the normalised coordinates
        inv_z = 1.0 / zs
        Jn = np.zeros(X.shape[:-1] + (2, 3))
        Jn[..., 0, 0] = inv_z
        Jn[..., 0, 2] = -x * inv_z
        Jn[..., 1, 1] = inv_z
        Jn[..., 1, 2] = -y * inv_z
        Jd = np.empty(X.shape[:-1] + (2, 2))
        Jd[..., 0, 0] = fx * dxd_dx
        Jd[..., 0, 1] = fx * dxd_dy
        Jd[..., 1, 0] = fy * dyd_dx
        Jd[..., 1, 1] = fy * dyd_dy
        Jp = Jd @ Jn
        Jk = np.zeros(X.shape[:-1] + (2, 9))
        Jk[..., 0, 0] = xd
        Jk[..., 1, 1] = yd
        Jk[..., 0, 2] = 1.0
        Jk[..., 1, 3] = 1.0
        for col, power in ((4, 1), (5, 2), (8, 3)):
            Jk[..., 0, col] = fx * x * r2**power
            Jk[..., 1, col] = fy * y * r2**power
        Jk[..., 0, 6] = fx * 2 * x * y
        Jk[..., 1, 6] = fy * (r2 + 2 * y * y)
        Jk[..., 0, 7] = fx * (r2 + 2 * x * x)
        Jk[..., 1, 7] = fy * 2 * x * y
        return uv, Jp, Jk

    def unproject(self, pixels):
        uv = _check_last_dim(pixels, 2, "pixels")
        fx, fy, cx, cy, k1, k2, p1, p2, k3 = self.params
        xd = (uv[..., 0] - cx) / fx
        yd = (uv[..., 1] - cy) / fy
        x, y = xd.copy(), yd.copy()
        # Newton on the undistorted normalised point; the distortion is monotone (checked at load).
        for _ in range(_NEWTON_STEPS):
            r2 = x * x + y * y
            rad = self._radial(r2)
            drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)
            fxv = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
            fyv = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
            a = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
            b = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            d = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
            det = a * d - b * b
            det = np.where(np.abs(det) < 1e-12, 1e-12, det)
            x = x - (d * fxv - b * fyv) / det
            y = y - (a * fyv - b * fxv) / det
        rays = np.stack([x, y, np.ones_like(x)], axis=-1)
        bearings = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
        theta = np.arccos(np.clip(bearings[..., 2], -1, 1))
        valid = (theta <= self.max_theta) & self.in_image(uv) & np.all(np.isfinite(bearings), axis=-1)
        return bearings, valid

    def project(self, points):
        uv, valid = super().project(points)
        X = np.asarray(points, dtype=float)
        return uv, valid & (X[..., 2] > 0) & (self.colatitude(X) < np.pi / 2)
