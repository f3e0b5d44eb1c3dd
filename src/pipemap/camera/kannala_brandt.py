"""OpenCV's fisheye model (Kannala-Brandt): d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)."""

from __future__ import annotations

import numpy as np

from pipemap.camera.radial import RadialFisheye
from pipemap.errors import PipemapError


class KannalaBrandtCamera(RadialFisheye):
    model = "kannala_brandt"
    param_names = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")

    def _validate(self):
        for i, name in enumerate(("fx", "fy")):
            if self.params[i] <= 0:
                raise PipemapError(f"focal length {name} must be positive, got {self.params[i]:g}",
                                   key=f"camera.params.{name}")

    def _radius(self, theta):
        k1, k2, k3, k4 = self.params[4:]
        t2 = theta * theta
        poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
        dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + 9 * k4 * t2)))
        return theta * poly, dpoly

    def _radius_coeff_basis(self, theta):
        t2 = theta * theta
        t3 = t2 * theta
        return np.stack([t3, t3 * t2, t3 * t2 * t2, t3 * t2 * t2 * t2], axis=-1)

    def _affine(self):
        fx, fy, cx, cy = self.params[:4]
        return float(fx), float(fy), float(cx), float(cy)

    def _param_layout(self):
        return {"fx": 0, "fy": 1, "cx": 2, "cy": 3, "coeffs": [4, 5, 6, 7]}
