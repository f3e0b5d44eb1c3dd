"""Where a tee passed straight through lies along the pipe: from the wall of its side branch.

When the robot drives straight through a tee, the pipe's axis does not turn, so the straight sections
either side cannot say where along the pipe the tee is; the frames the classification labels as a
junction only say roughly when its opening was in view, and a distant view of a tee ahead or a moment
of classification flicker makes such a cluster with no tee at all. What does place the tee is its side
opening: the camera looks into the branch as it passes, and the corners it tracks on the branch's wall
are triangulated off the wall of the pipe it drives through. They lie on the branch cylinder, of the
same radius r, whose axis crosses the through axis at the tee centre I.

The model: the through cylinder (origin O, unit axis z, frame e1, e2 across it) is known; the branch
axis passes through I = O + c z with direction

    u(phi, psi) = cos psi (cos phi e1 + sin phi e2) + sin psi z,

phi its direction around the through pipe, psi its tilt from square (0 for a tee, about 45 deg for a
wye). A point P lies on the branch wall when d = |q| = r, with w = P - I, a = w . u and q = w - a u.
(c, phi, psi) minimise the Huber cost of d - r over the points beyond the through pipe's wall, by
Levenberg-Marquardt with MAD outlier passes between runs. The branch axis is a whole line, so a cross
(openings on both sides) fits the same way; the inliers on either side of the through axis tell a tee
from a cross.

Because q is perpendicular to u, the derivatives of d are (q / d) . (dw - a du):
    dd/dc = -(q . z) / d,  dd/dphi = -a (q . du/dphi) / d,  dd/dpsi = -a (q . du/dpsi) / d.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.geometry.cylinder import Cylinder, axis_frame
from pipemap.solvers.lm import levenberg_marquardt
from pipemap.solvers.robust import huber_irls, mad_inliers

CROSS_SHARE = 0.25  # a second opening needs at least this share of the inliers across the through axis


@dataclass(frozen=True)
class SideOpening:
    """The branch cylinder found beside the through pipe."""

    centre: np.ndarray  # I, world (3,)
    h: float  # I's axial coordinate on the through cylinder
    azimuth_deg: float  # phi: the branch's direction around the through axis, from axis_frame's x axis
    tilt_deg: float  # psi: 0 for a square tee
    openings: int  # 1: a tee, 2: a cross
    points: int  # inliers on the branch wall
    rms_m: float  # RMS of their distances to the branch wall
    sigma_h_m: float  # standard deviation of h
    direction: np.ndarray | None = None  # u, world, from I into the (larger) opening

    @property
    def kind(self) -> str:
        return "cross" if self.openings == 2 else "tee"

    def to_dict(self) -> dict:
        return {"h_m": round(self.h, 6), "azimuth_deg": round(self.azimuth_deg, 3), "tilt_deg": round(self.tilt_deg, 3),
                "openings": self.openings, "points": self.points, "rms_m": round(self.rms_m, 6),
                "sigma_h_m": round(self.sigma_h_m, 6)}


def branch_direction(frame: np.ndarray, phi: float, psi: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u and its derivatives by phi and psi; `frame` columns are e1, e2, z."""
    e1, e2, z = frame.T
    across = np.cos(phi) * e1 + np.sin(phi) * e2
    u = np.cos(psi) * across + np.sin(psi) * z
    du_dphi = np.cos(psi) * (-np.sin(phi) * e1 + np.cos(phi) * e2)
    du_dpsi = -np.sin(psi) * across + np.cos(psi) * z
    return u, du_dphi, du_dpsi


def branch_residuals(points: np.ndarray, through: Cylinder, params: np.ndarray,
                     radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(d - r (n,), Jacobian (n, 3) by (c, phi, psi)) of points against the branch cylinder."""
    frame = axis_frame(through.direction)
    z = frame[:, 2]
    c, phi, psi = params
    u, du_dphi, du_dpsi = branch_direction(frame, phi, psi)
    w = points - (through.origin + c * z)
    a = w @ u
    q = w - a[:, None] * u
    d = np.maximum(np.linalg.norm(q, axis=1), 1e-12)
    J = np.stack([-(q @ z) / d, -a * (q @ du_dphi) / d, -a * (q @ du_dpsi) / d], axis=1)
    return d - radius, J


def _candidates(points: np.ndarray, through: Cylinder, h_guess: float, reach: float) -> np.ndarray:
    """Rows beyond the through pipe's wall (by a tenth of its radius) and within `reach` radii of it
    across and of the guess along it."""
    r = through.radius
    h = through.axial(points)
    rho = np.linalg.norm(points - through.origin - np.outer(h, through.direction), axis=1)
    return np.flatnonzero((rho > 1.1 * r) & (rho < (1.0 + reach) * r) & (np.abs(h - h_guess) < (1.0 + reach) * r))


def _start(points: np.ndarray, through: Cylinder) -> np.ndarray:
    """c at the points' median along the axis, phi at their axial mean direction (a tee's one opening or a
    cross's two), psi square."""
    frame = axis_frame(through.direction)
    rel = points - through.origin
    phi = np.arctan2(rel @ frame[:, 1], rel @ frame[:, 0])
    axial_mean = 0.5 * np.arctan2(np.sin(2 * phi).sum(), np.cos(2 * phi).sum())
    return np.array([float(np.median(through.axial(points))), axial_mean, 0.0])


def fit_side_opening(points: np.ndarray, through: Cylinder, h_guess: float, *, huber_m: float, mad_k: float,
                     outlier_passes: int, reach_radii: float = 2.0, min_points: int = 30,
                     max_sigma_m: float = np.inf, iterations: int = 30) -> SideOpening | None:
    """The side branch beside `through` near its axial coordinate `h_guess`, from scene points (n, 3);
    None when fewer than `min_points` points lie on a branch wall or the centre is looser than
    `max_sigma_m` along the pipe (no opening: nothing branches off here)."""
    rows = _candidates(np.asarray(points, float), through, h_guess, reach_radii)
    if len(rows) < min_points:
        return None
    P = np.asarray(points, float)[rows]
    r = through.radius
    params = _start(P, through)
    inliers = np.ones(len(P), bool)
    for _ in range(outlier_passes + 1):
        sel = P[inliers]
        res = levenberg_marquardt(lambda x: branch_residuals(sel, through, x, r), lambda x, s: x + s, params,
                                  iterations=iterations, cost=huber_irls(huber_m))
        params = res.state
        e, _ = branch_residuals(P, through, params, r)
        inliers = mad_inliers(e, mad_k, floor=huber_m)
        if inliers.sum() < min_points:
            return None
    e, J = branch_residuals(P[inliers], through, params, r)
    rms = float(np.sqrt(np.mean(e * e)))
    try:
        cov = rms * rms * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return None
    sigma_h = float(np.sqrt(max(cov[0, 0], 0.0)))
    if not np.isfinite(sigma_h) or sigma_h > max_sigma_m:
        return None
    c, phi, psi = params
    u, _, _ = branch_direction(axis_frame(through.direction), phi, psi)
    side = (P[inliers] - (through.origin + c * through.direction)) @ u
    if (side < 0).sum() > (side > 0).sum():  # point u at the opening (a tee's only one, a cross's larger one)
        phi, psi, side = phi + np.pi, -psi, -side
    openings = 2 if min((side > 0).sum(), (side < 0).sum()) >= CROSS_SHARE * len(side) else 1
    phi = float(np.angle(np.exp(1j * phi)))
    u, _, _ = branch_direction(axis_frame(through.direction), phi, psi)
    return SideOpening(through.origin + c * through.direction, float(c), float(np.degrees(phi)),
                       float(np.degrees(psi)), openings, int(inliers.sum()), rms, sigma_h, u)


__all__ = ["SideOpening", "fit_side_opening", "branch_residuals", "branch_direction"]
