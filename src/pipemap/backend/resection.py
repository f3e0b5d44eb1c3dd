"""A keyframe's pose from the scene points it sees (motion-only bundle adjustment on bearings).

The front end's five-point pose between two keyframes is well determined when the view is wide: a
fisheye sees the wall all round and beside the camera. A perspective camera looking along the pipe
sees the wall ahead in a cone of a few tens of degrees, where a small rotation and a sideways
translation move the image alike: its five-point translation wanders by degrees and its rotation by
tenths of a degree between keyframes (measured on a 60 deg forward camera: 7-20 deg and 0.3-0.6 deg,
against 1-2 deg and 0.05-0.2 deg on a 100 deg one). Scene points already triangulated carry the
depth that separates the two, so the pose is refined against them: Huber-weighted angular errors on
the view sphere, Levenberg-Marquardt over the right perturbation of (R, c).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.backend.angular import angular_residuals, refine_huber, tangent_bases
from pipemap.geometry.se3 import camera_point_jacobian, retract, world_to_camera


class ResectionProblem:
    """Angular errors (2M,) of world points X seen from the camera (R, c) against bearings b."""

    def __init__(self, R: np.ndarray, c: np.ndarray, X: np.ndarray, b: np.ndarray, bases: np.ndarray | None = None):
        self.R, self.c, self.X, self.b = R, c, X, b
        self.B = tangent_bases(b) if bases is None else bases

    def moved(self, delta) -> "ResectionProblem":
        return ResectionProblem(*retract(self.R, self.c, delta), self.X, self.b, self.B)

    def residuals(self, delta=None, jacobian: bool = False):
        R, c = (self.R, self.c) if delta is None else retract(self.R, self.c, delta)
        Xc = world_to_camera(R, c, self.X)
        if not jacobian:
            return angular_residuals(Xc, self.b, self.B).ravel()
        if delta is not None and np.any(delta):
            raise ValueError("the Jacobian is taken at delta = 0; move the problem first")
        r, A = angular_residuals(Xc, self.b, self.B, True)
        return r.ravel(), (A @ camera_point_jacobian(Xc)).reshape(-1, 6)

    def errors(self) -> np.ndarray:
        return np.linalg.norm(self.residuals().reshape(-1, 2), axis=1)


@dataclass(frozen=True)
class Resection:
    R: np.ndarray  # (3, 3) camera -> world
    c: np.ndarray  # (3,) camera centre
    inliers: np.ndarray  # (M,) bool: angular error within 3 Huber thresholds after the solve


def resect(R: np.ndarray, c: np.ndarray, points: np.ndarray, bearings: np.ndarray, huber_rad: float,
           iterations: int = 10) -> Resection:
    """Refine the pose (R, c) against world points (M, 3) observed at unit bearings (M, 3)."""
    problem = ResectionProblem(np.asarray(R, float), np.asarray(c, float), np.asarray(points, float),
                               np.asarray(bearings, float))
    problem = refine_huber(problem, huber_rad, iterations)
    return Resection(problem.R, problem.c, problem.errors() < 3 * huber_rad)


__all__ = ["ResectionProblem", "Resection", "resect"]
