"""The fisheye paper's polynomial model (eq. 1): r = k1 theta + k2 theta^3 + k3 theta^4 + k4 theta^5."""

from __future__ import annotations

import numpy as np

from pipemap.camera.radial import RadialFisheye
from pipemap.errors import PipemapError


class PolynomialCamera(RadialFisheye):
    model = "polynomial"
    param_names = ("k1", "k2", "k3", "k4", "u0", "v0")

    def _validate(self):
        if self.params[0] <= 0:
            raise PipemapError(f"focal length k1 must be positive, got {self.params[0]:g}", key="camera.params.k1")

    def _radius(self, theta):
        k1, k2, k3, k4 = self.params[:4]
        t2 = theta * theta
        d = theta * (k1 + t2 * (k2 + theta * (k3 + theta * k4)))
        dd = k1 + t2 * (3 * k2 + theta * (4 * k3 + 5 * k4 * theta))
        return d, dd

    def _radius_coeff_basis(self, theta):
        t2 = theta * theta
        return np.stack([theta, t2 * theta, t2 * t2, t2 * t2 * theta], axis=-1)

    def _affine(self):
        return 1.0, 1.0, float(self.params[4]), float(self.params[5])

    def _param_layout(self):
        return {"fx": None, "fy": None, "cx": 4, "cy": 5, "coeffs": [0, 1, 2, 3]}
