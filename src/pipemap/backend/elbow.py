"""Elbows: a junction pass where the axis turns and no pipe runs on past the turn.

At a tee the robot turns from one pipe into another, and one of the two runs on through the junction:
its wall lies beyond the point I where the axes meet (a stub, or the main pipe). An elbow is one
bent pipe: its axis is a circular arc of bend radius rho joined tangentially to the straight axes
either side, so nothing lies beyond the vertex V where the straight axes meet; the wall there is the
outside of the bend. `pipe_beyond` counts the points on either straight cylinder's wall more than
1.5 radii past V; a turning pass with no such pipe is an elbow.

Its vertex and angle are those of the two straight sections' end cylinders (their closest approach,
the angle between them); its bend radius is fitted to the wall points of the bend. With unit axis
directions d1 (into V) and d2 (out of it) at an angle theta, the arc of radius rho tangent to both
leaves the first axis at V - T d1, T = rho tan(theta / 2), and has its centre at C = V - T d1 + rho n,
n the unit normal to d1 towards d2 in their plane (normal b). A point P lies on the bend's wall when

    e = sqrt((s - rho)^2 + z^2) - r = 0,   p = P - C, z = p . b, q = p - z b, s = |q|,

over the points whose direction q from C lies within the arc. dC/drho = g = n - tan(theta / 2) d1
lies in the plane, so dz/drho = 0, ds/drho = -(q / s) . g and de/drho = (s - rho)(ds/drho - 1) / (e + r).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.geometry.cylinder import Cylinder
from pipemap.solvers.lm import levenberg_marquardt
from pipemap.solvers.robust import huber_irls, mad_inliers

BEYOND_RADII = 1.5  # a pipe running on through the junction shows this far past the vertex
ARC_MARGIN_DEG = 3.0  # points this close to either end of the arc could be the straight pipe's


@dataclass(frozen=True)
class Bend:
    """The arc of an elbow's axis between the two straight axes."""

    vertex: np.ndarray  # V (3,)
    d1: np.ndarray  # unit direction of the first axis, into V
    d2: np.ndarray  # ... of the second, out of V
    angle_deg: float  # theta, how far the axis turns

    @property
    def normal(self) -> np.ndarray:  # b, the normal of the bend's plane
        b = np.cross(self.d1, self.d2)
        return b / np.linalg.norm(b)

    @property
    def inward(self) -> np.ndarray:  # n, towards the inside of the turn, across d1
        n = self.d2 - (self.d2 @ self.d1) * self.d1
        return n / np.linalg.norm(n)

    def centre(self, rho: float) -> np.ndarray:
        return self.vertex - rho * np.tan(np.radians(self.angle_deg) / 2) * self.d1 + rho * self.inward


@dataclass(frozen=True)
class ElbowFit:
    bend_radius_m: float
    sigma_m: float  # standard deviation of the bend radius
    points: int  # wall points of the bend used
    rms_m: float


def bend_of(a: Cylinder, b: Cylinder, vertex: np.ndarray) -> Bend:
    """The bend from cylinder a into cylinder b meeting at `vertex`. Each end cylinder's origin is the foot of
    a camera centre beside the junction: a's lies before the vertex, b's beyond it, which orients the axes."""
    vertex = np.asarray(vertex, float)
    d1 = a.direction if (vertex - a.origin) @ a.direction >= 0 else -a.direction
    d2 = b.direction if (b.origin - vertex) @ b.direction >= 0 else -b.direction
    angle = float(np.degrees(np.arccos(np.clip(d1 @ d2, -1.0, 1.0))))
    return Bend(vertex, d1, d2, angle)


def model_bend(model, red_pose) -> Bend:
    """The bend of an elbow's tee model (`pipemap.geometry.tee.TeeModel`, its vertex the model's I) given T_wc of
    P_r: P_r lies before the vertex and P_b beyond it, which orients the axes."""
    R, t = red_pose if isinstance(red_pose, tuple) else (red_pose[:3, :3], red_pose[:3, 3])
    vertex = model.intersection((R, t))
    a, b = model.red_cylinder((R, t)).direction, model.blue_cylinder((R, t)).direction
    d1 = a if (vertex - t) @ a >= 0 else -a
    d2 = b if (model.blue_pose((R, t))[:3, 3] - vertex) @ b >= 0 else -b
    return Bend(vertex, d1, d2, float(np.degrees(np.arccos(np.clip(d1 @ d2, -1.0, 1.0)))))


def bend_residuals(points: np.ndarray, bend: Bend, rho: float, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(e (n,), de/drho (n, 1)) of points against the bend's wall of bend radius rho."""
    th = np.radians(bend.angle_deg)
    C = bend.centre(rho)
    g = bend.inward - np.tan(th / 2) * bend.d1
    p = points - C
    z = p @ bend.normal
    q = p - np.outer(z, bend.normal)
    s = np.maximum(np.linalg.norm(q, axis=1), 1e-12)
    dist = np.sqrt((s - rho) ** 2 + z * z)
    e = dist - radius
    ds = -(q @ g) / s
    return e, ((s - rho) * (ds - 1.0) / np.maximum(dist, 1e-12))[:, None]


def bend_normals(points: np.ndarray, bend: Bend, rho: float) -> np.ndarray:
    """(n, 3) d e / d P: the unit normal of the bend's wall (the torus) at each point's nearest wall point."""
    p = points - bend.centre(rho)
    z = p @ bend.normal
    q = p - np.outer(z, bend.normal)
    s = np.maximum(np.linalg.norm(q, axis=1), 1e-12)
    g = (1.0 - rho / s)[:, None] * q + z[:, None] * bend.normal
    return g / np.maximum(np.linalg.norm(g, axis=1), 1e-12)[:, None]


def on_arc(points: np.ndarray, bend: Bend, rho: float, margin_deg: float = ARC_MARGIN_DEG) -> np.ndarray:
    """Which points lie, seen from the arc's centre, within the arc less `margin_deg` at either end (a negative
    margin widens it)."""
    C = bend.centre(rho)
    p = points - C
    q = p - np.outer(p @ bend.normal, bend.normal)
    start = -bend.inward  # from C to where the arc leaves the first axis
    along = np.cross(bend.normal, start)  # the direction the arc turns through from `start`
    if along @ bend.d1 < 0:
        along = -along
    phi = np.degrees(np.arctan2(q @ along, q @ start))
    return (phi > margin_deg) & (phi < bend.angle_deg - margin_deg)


def fit_bend_radius(points: np.ndarray, bend: Bend, radius: float, *, huber_m: float, mad_k: float,
                    outlier_passes: int, min_points: int = 30, rounds: int = 4) -> ElbowFit | None:
    """The bend radius of the wall points (n, 3) around the bend; None when too few lie on its arc. Starts at
    2 pipe diameters; the points on the arc are chosen again after each round."""
    P = np.asarray(points, float)
    rho = 4.0 * radius
    for _ in range(rounds):
        sel = P[on_arc(P, bend, rho)]
        if len(sel) < min_points:
            return None
        inliers = np.ones(len(sel), bool)
        for _ in range(outlier_passes + 1):
            use = sel[inliers]
            res = levenberg_marquardt(lambda x: bend_residuals(use, bend, float(x[0]), radius),
                                      lambda x, step: np.maximum(x + step, 0.05 * radius), np.array([rho]),
                                      cost=huber_irls(huber_m))
            rho = float(res.state[0])
            inliers = mad_inliers(bend_residuals(sel, bend, rho, radius)[0], mad_k, floor=huber_m)
            if inliers.sum() < min_points:
                return None
    e, J = bend_residuals(sel[inliers], bend, rho, radius)
    rms = float(np.sqrt(np.mean(e * e)))
    sigma = float(rms / np.sqrt(max(float(J[:, 0] @ J[:, 0]), 1e-300)))
    return ElbowFit(rho, sigma, int(inliers.sum()), rms)


def pipe_beyond(points: np.ndarray, a: Cylinder, b: Cylinder, bend: Bend, tolerance_m: float) -> tuple[int, int]:
    """Points on a's wall more than BEYOND_RADII radii past the vertex along d1, and on b's wall as far before
    it (against d2), each off the other cylinder's wall: the pipe that runs on through a tee."""
    r = a.radius
    da, db = np.abs(a.distance(points)), np.abs(b.distance(points))
    past_a = (points - bend.vertex) @ bend.d1 > BEYOND_RADII * r
    before_b = (points - bend.vertex) @ bend.d2 < -BEYOND_RADII * r
    on_a = past_a & (da < tolerance_m) & (db > tolerance_m)
    on_b = before_b & (db < tolerance_m) & (da > tolerance_m)
    return int(on_a.sum()), int(on_b.sum())


__all__ = ["Bend", "ElbowFit", "model_bend", "bend_normals", "bend_of", "bend_residuals", "on_arc", "fit_bend_radius",
           "pipe_beyond"]
