"""The interface every camera model implements, vectorised over (..., 3) and (..., 2) arrays."""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from pipemap.errors import PipemapError


class CameraModel(ABC):
    """A central camera: 3D points in the camera frame (x right, y down, z forward) <-> pixels.

    `project` returns pixels and a validity mask (inside the field of view up to
    `max_theta` and inside the image); `unproject` returns unit bearing vectors, also past
    90 degrees for fisheye models.
    """

    model: ClassVar[str]
    param_names: ClassVar[tuple[str, ...]]

    def __init__(self, width: int, height: int, params, max_theta_deg: float | None = None):
        if (not (isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer)))
                or width <= 0 or height <= 0):
            raise PipemapError(f"image size must be positive integers, got {width}x{height}", key="camera.width/height")
        self.width = int(width)
        self.height = int(height)
        if isinstance(params, dict):
            missing = [k for k in self.param_names if k not in params]
            unknown = [k for k in params if k not in self.param_names]
            if missing:
                raise PipemapError(f"{self.model} camera is missing {', '.join(missing)}", key="camera.params")
            if unknown:
                raise PipemapError(
                    f"{self.model} camera has no parameter {', '.join(unknown)} "
                    f"(expected {' '.join(self.param_names)})",
                    key="camera.params",
                )
            try:
                params = [float(params[k]) for k in self.param_names]
            except (TypeError, ValueError):
                raise PipemapError("camera parameters must be numbers", key="camera.params") from None
        p = np.asarray(params, dtype=float).reshape(-1)
        if p.shape != (len(self.param_names),):
            raise PipemapError(f"{self.model} camera takes {len(self.param_names)} parameters, got {p.size}",
                               key="camera.params")
        if not np.all(np.isfinite(p)):
            raise PipemapError("camera parameters must be finite", key="camera.params")
        self.params = p
        self._given_max_theta_deg = None if max_theta_deg is None else float(max_theta_deg)
        self._validate()
        self.max_theta = self._resolve_max_theta(self._given_max_theta_deg)

    # -- model-specific parts -------------------------------------------------------------

    @abstractmethod
    def _validate(self) -> None:
        """Raise PipemapError for parameters that do not describe a camera."""

    @abstractmethod
    def _resolve_max_theta(self, given_deg: float | None) -> float:
        """The largest colatitude (radians) inside the field of view; checks monotonicity up to it."""

    @abstractmethod
    def _project(self, X: np.ndarray, jacobians: bool):
        """Return pixels (..., 2) and, with jacobians, d/dpoint (..., 2, 3) and d/dparams (..., 2, P)."""

    @abstractmethod
    def unproject(self, pixels) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (..., 2) -> (unit bearings (..., 3), valid (...))."""

    # -- shared machinery -------------------------------------------------------------------

    @property
    def max_theta_deg(self) -> float:
        return float(np.degrees(self.max_theta))

    def view_colatitudes(self) -> tuple[float, float]:
        """(inscribed, widest), radians: the largest colatitude the image shows in every direction
        around the optical axis, and the largest it shows in any direction (the image corners of a
        perspective camera, the rim of a fisheye's circle). Stages that work in bands of colatitude
        take their limits from these rather than from one lens."""
        key = (self.width, self.height, tuple(self.params.tolist()), self.max_theta)
        if getattr(self, "_view_key", None) != key:
            theta = np.linspace(0.0, self.max_theta, int(np.ceil(np.degrees(self.max_theta) * 10)) + 1)
            phi = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
            rays = bearings_from_angles(*np.broadcast_arrays(theta[None, :], phi[:, None]))
            _, valid = self.project(rays)
            valid[:, 0] = True
            # the field of view in one direction ends at its first ray outside the image
            last = np.where(valid.all(axis=1), len(theta) - 1, np.argmin(valid, axis=1) - 1)
            reach = theta[last]
            self._view_key, self._view = key, (float(reach.min()), float(reach.max()))
        return self._view

    def sees_beside(self) -> bool:
        """Whether the image holds the wall beside the camera (colatitude 90 deg) in some direction: a fisheye
        does, a forward perspective camera sees the pipe only ahead."""
        return self.view_colatitudes()[1] >= np.pi / 2

    def param_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in zip(self.param_names, self.params)}

    def with_params(self, params) -> "CameraModel":
        return type(self)(self.width, self.height, params, self._given_max_theta_deg)

    def for_optimiser(self, params) -> "CameraModel":
        """A copy with new parameters whose `project_jacobian` is usable even when the parameters fail
        validation: an optimiser's trial steps may cross such a region on the way to the true camera.
        Only the projection maths is meaningful on it; build a checked camera for the final result."""
        trial = copy.copy(self)
        trial.params = np.asarray(params, dtype=float).reshape(self.params.shape)
        return trial

    def in_image(self, pixels: np.ndarray) -> np.ndarray:
        u, v = pixels[..., 0], pixels[..., 1]
        lo, eps = -0.5 - 1e-6, 1e-6  # tolerate round-off on the border of the image
        return (u >= lo) & (u <= self.width - 0.5 + eps) & (v >= lo) & (v <= self.height - 0.5 + eps)

    def colatitude(self, points) -> np.ndarray:
        X = np.asarray(points, dtype=float)
        return np.arctan2(np.hypot(X[..., 0], X[..., 1]), X[..., 2])

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Points (..., 3) in the camera frame -> (pixels (..., 2), valid (...))."""
        X = _check_last_dim(points, 3, "points")
        uv = self._project(X, jacobians=False)[0]
        valid = (self.colatitude(X) <= self.max_theta) & self.in_image(uv) & np.all(np.isfinite(uv), axis=-1)
        return uv, valid

    def project_jacobian(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points (..., 3) -> pixels (..., 2), d pixels / d point (..., 2, 3), d pixels / d params (..., 2, P)."""
        X = _check_last_dim(points, 3, "points")
        return self._project(X, jacobians=True)

    def to_dict(self) -> dict:
        d = {"model": self.model, "width": self.width, "height": self.height, "params": self.param_dict()}
        if self._given_max_theta_deg is not None:
            d["max_theta_deg"] = self._given_max_theta_deg
        return d

    def __repr__(self) -> str:
        ps = ", ".join(f"{k}={v:.6g}" for k, v in self.param_dict().items())
        return f"{type(self).__name__}({self.width}x{self.height}, {ps}, max_theta={self.max_theta_deg:.1f} deg)"


def _check_last_dim(a, n: int, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim == 0 or a.shape[-1] != n:
        raise ValueError(f"{name} must have shape (..., {n}), got {a.shape}")
    return a


def bearings_from_angles(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)
