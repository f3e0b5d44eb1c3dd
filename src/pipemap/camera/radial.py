"""Shared maths of the fisheye models: image radius is a monotone function d(theta) of colatitude.

u = cx + fx * d(theta) * cos(phi),  v = cy + fy * d(theta) * sin(phi)
"""

from __future__ import annotations

from abc import abstractmethod

import numpy as np

from pipemap.camera.base import CameraModel, _check_last_dim, bearings_from_angles
from pipemap.errors import PipemapError

_TABLE_SIZE = 4096
_NEWTON_STEPS = 5


class RadialFisheye(CameraModel):
    """Base of `polynomial` and `kannala_brandt`: subclasses give d(theta) and the affine part."""

    @abstractmethod
    def _radius(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d(theta) and d'(theta)."""

    @abstractmethod
    def _radius_coeff_basis(self, theta: np.ndarray) -> np.ndarray:
        """(..., 4): d d(theta) / d coefficient for the four distortion coefficients."""

    @abstractmethod
    def _affine(self) -> tuple[float, float, float, float]:
        """fx, fy, cx, cy."""

    @abstractmethod
    def _param_layout(self) -> dict[str, int | list[int] | None]:
        """Indices into params of fx, fy, cx, cy (None when fixed) and the four coefficients."""

    # -- field of view ----------------------------------------------------------------------

    def _monotone_limit(self) -> float:
        """Largest theta in (0, pi] up to which d(theta) keeps increasing."""
        theta = np.linspace(0.0, np.pi, 20001)
        _, dd = self._radius(theta)
        bad = np.nonzero(dd <= 0)[0]
        return float(np.pi if bad.size == 0 else theta[max(bad[0] - 1, 0)])

    def _resolve_max_theta(self, given_deg):
        limit = self._monotone_limit()
        if given_deg is not None:
            if not 0 < given_deg <= 180:
                raise PipemapError(f"max_theta_deg must be in (0, 180], got {given_deg}", key="camera.max_theta_deg")
            if np.radians(given_deg) > limit + 1e-9:
                raise PipemapError(
                    f"the {self.model} projection is not monotone over the field of view: d(theta) turns back at "
                    f"{np.degrees(limit):.1f} deg < max_theta_deg {given_deg:g}",
                    key="camera.params",
                )
            max_theta = np.radians(given_deg)
        else:
            fx, fy, cx, cy = self._affine()
            corners = np.array([[-0.5, -0.5], [self.width - 0.5, -0.5], [-0.5, self.height - 0.5],
                                [self.width - 0.5, self.height - 0.5]])
            reach = np.max(np.hypot((corners[:, 0] - cx) / fx, (corners[:, 1] - cy) / fy))
            theta = np.linspace(0.0, limit, 20001)
            d, _ = self._radius(theta)
            idx = np.searchsorted(d, reach)
            max_theta = float(theta[min(idx, theta.size - 1)])
        if max_theta < np.radians(5.0):
            raise PipemapError(
                f"the {self.model} projection is not monotone over the field of view "
                f"(only up to {np.degrees(max_theta):.2f} deg)",
                key="camera.params",
            )
        # Inverse table used to seed Newton's method in unproject().
        self._table_theta = np.linspace(0.0, max(max_theta, min(limit, max_theta * 1.05)), _TABLE_SIZE)
        self._table_d, _ = self._radius(self._table_theta)
        return max_theta

    # -- projection -------------------------------------------------------------------------

    def _project(self, X, jacobians):
        fx, fy, cx, cy = self._affine()
        x, y, z = X[..., 0], X[..., 1], X[..., 2]
        rho = np.hypot(x, y)
        n2 = rho * rho + z * z
        theta = np.arctan2(rho, z)
        d, dd = self._radius(theta)
        on_axis = rho < 1e-12 * np.sqrt(np.maximum(n2, 1e-300))
        rho_s = np.where(on_axis, 1.0, rho)
        # a = d / rho; on the axis the limit is d'(0) / z.
        a = np.where(on_axis, dd / np.where(z == 0, 1.0, z), d / rho_s)
        uv = np.stack([cx + fx * a * x, cy + fy * a * y], axis=-1)
        if not jacobians:
            return uv, None, None
        # da/drho = (d'(theta) * z / n2 * rho - d) / rho^2
        dadrho_over_rho = np.where(on_axis, 0.0, (dd * z / n2 * rho - d) / rho_s**3)
        dddz = -dd / np.where(n2 == 0, 1.0, n2)  # d(theta) / dz * ... : dtheta/dz = -rho / n2, times 1/rho
        Jp = np.empty(X.shape[:-1] + (2, 3))
        Jp[..., 0, 0] = fx * (a + x * x * dadrho_over_rho)
        Jp[..., 0, 1] = fx * (x * y * dadrho_over_rho)
        Jp[..., 0, 2] = fx * x * dddz
        Jp[..., 1, 0] = fy * (x * y * dadrho_over_rho)
        Jp[..., 1, 1] = fy * (a + y * y * dadrho_over_rho)
        Jp[..., 1, 2] = fy * y * dddz
        cphi = np.where(on_axis, 0.0, x / rho_s)
        sphi = np.where(on_axis, 0.0, y / rho_s)
        layout = self._param_layout()
        Jk = np.zeros(X.shape[:-1] + (2, len(self.param_names)))
        basis = self._radius_coeff_basis(theta)
        for i, col in enumerate(layout["coeffs"]):
            Jk[..., 0, col] = fx * basis[..., i] * cphi
            Jk[..., 1, col] = fy * basis[..., i] * sphi
        if layout["fx"] is not None:
            Jk[..., 0, layout["fx"]] = a * x
        if layout["fy"] is not None:
            Jk[..., 1, layout["fy"]] = a * y
        Jk[..., 0, layout["cx"]] = 1.0
        Jk[..., 1, layout["cy"]] = 1.0
        return uv, Jp, Jk

    def theta_from_radius(self, d: np.ndarray) -> np.ndarray:
        """Invert d(theta) (monotone table + Newton), clipped to the table's range."""
        d = np.asarray(d, dtype=float)
        theta = np.interp(d, self._table_d, self._table_theta)
        hi = self._table_theta[-1]
        for _ in range(_NEWTON_STEPS):
            f, df = self._radius(theta)
            theta = np.clip(theta - (f - d) / np.maximum(df, 1e-12), 0.0, hi)
        return theta

    def unproject(self, pixels):
        uv = _check_last_dim(pixels, 2, "pixels")
        fx, fy, cx, cy = self._affine()
        mx = (uv[..., 0] - cx) / fx
        my = (uv[..., 1] - cy) / fy
        d = np.hypot(mx, my)
        theta = self.theta_from_radius(d)
        phi = np.arctan2(my, mx)
        bearings = bearings_from_angles(theta, phi)
        d_max, _ = self._radius(np.array(self.max_theta))
        valid = (d <= d_max + 1e-9) & self.in_image(uv)
        return bearings, valid
