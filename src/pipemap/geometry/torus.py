"""Tori (an elbow's bent pipe): exact ray intersection and the distance to the wall, vectorised.

A torus here is the tube of minor radius `r` around a circle of radius `R` (the bend radius) about
the z axis in its own frame. Everything works in that frame with lengths divided by R, so that the
quartic's coefficients stay near 1 whatever the pipe's size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _largest_cubic_root(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """The largest real root of x^3 + A x^2 + B x + C (arrays), polished by two Newton steps."""
    P = B - A * A / 3
    Q = 2 * A**3 / 27 - A * B / 3 + C
    D = (Q / 2) ** 2 + (P / 3) ** 3
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.maximum(D, 0.0))
        one = np.cbrt(-Q / 2 + sq) + np.cbrt(-Q / 2 - sq)
        m = np.sqrt(np.maximum(-P / 3, 0.0))
        arg = np.clip(np.where(m > 0, -Q / (2 * np.maximum(m, 1e-300) ** 3), 0.0), -1.0, 1.0)
        three = 2 * m * np.cos(np.arccos(arg) / 3)
    y = np.where(D > 0, one, three) - A / 3
    for _ in range(2):
        f = ((y + A) * y + B) * y + C
        df = (3 * y + 2 * A) * y + B
        y = np.where(np.abs(df) > 1e-300, y - f / np.where(df == 0, 1.0, df), y)
    return y


def _quadratic(B: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Real roots of y^2 + B y + C (NaN where complex), cancellation-free."""
    disc = B * B - 4 * C
    s = np.sqrt(np.maximum(disc, 0.0))
    q = -(B + np.copysign(s, B)) / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = q
        r2 = np.where(q != 0, C / np.where(q == 0, 1.0, q), 0.0)
    ok = disc >= 0
    return np.where(ok, r1, np.nan), np.where(ok, r2, np.nan)


def quartic_real_roots(a, b, c, d, polish: int = 3) -> np.ndarray:
    """Real roots of x^4 + a x^3 + b x^2 + c x + d for arrays of coefficients: (N, 4), NaN where a root
    is complex. Ferrari's method (the resolvent cubic's largest root factors the depressed quartic into two
    quadratics), then `polish` Newton steps on the quartic itself."""
    a, b, c, d = np.broadcast_arrays(*(np.asarray(x, float) for x in (a, b, c, d)))
    a2 = a * a
    p = b - 3 * a2 / 8
    q = c - a * b / 2 + a2 * a / 8
    s = d - a * c / 4 + a2 * b / 16 - 3 * a2 * a2 / 256
    u = _largest_cubic_root(-p / 2, -s, p * s / 2 - q * q / 8)
    w = np.sqrt(np.maximum(2 * u - p, 0.0))
    scale = 1.0 + np.abs(p) + np.sqrt(np.abs(s))
    with np.errstate(divide="ignore", invalid="ignore"):
        # q / (2 w), or where w vanishes (a biquadratic) its limit sign(q) sqrt(u^2 - s)
        m = np.where(w > 1e-7 * scale, q / (2 * np.where(w > 0, w, 1.0)),
                     np.copysign(np.sqrt(np.maximum(u * u - s, 0.0)), q))
    y = np.stack(_quadratic(-w, u + m) + _quadratic(w, u - m), axis=-1)
    x = y - (a / 4)[..., None]
    A, B, C, D = (v[..., None] for v in (a, b, c, d))
    for _ in range(polish):
        f = (((x + A) * x + B) * x + C) * x + D
        df = ((4 * x + 3 * A) * x + 2 * B) * x + C
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(np.abs(df) > 0, f / df, 0.0)
        x = np.where(np.isfinite(step), x - step, x)
    return x


def ray_torus(origin: np.ndarray, dirs: np.ndarray, minor: float) -> np.ndarray:
    """Distances t (N, 4), ascending, NaN where absent, at which rays origin + t dirs meet the torus of bend
    radius 1 and tube radius `minor` about the z axis (its own frame, lengths in bend radii). `origin` (3,) or
    one per ray (3, N), `dirs` (3, N) unit vectors as components."""
    o = np.asarray(origin, float)
    dx, dy, dz = (np.asarray(v, float) for v in dirs)
    k = o[0] * dx + o[1] * dy + o[2] * dz
    m = o[0] ** 2 + o[1] ** 2 + o[2] ** 2 + 1.0 - minor * minor
    a = 4 * k
    b = 4 * k * k + 2 * m - 4 * (dx * dx + dy * dy)
    c = 4 * k * m - 8 * (o[0] * dx + o[1] * dy)
    d = np.broadcast_to(m * m - 4 * (o[0] ** 2 + o[1] ** 2), k.shape)
    return np.sort(quartic_real_roots(a, b, c, d), axis=-1)


@dataclass(frozen=True)
class TorusPiece:
    """An elbow's solid bent tube: the points within `radius` of the arc of radius `bend_radius` about `centre`
    that turns anticlockwise about the unit `normal` by `angle` radians (below pi) from the unit direction `e1`
    (from the centre to the arc's start)."""

    centre: np.ndarray
    normal: np.ndarray
    e1: np.ndarray
    bend_radius: float
    angle: float
    radius: float

    @property
    def basis(self) -> np.ndarray:
        """Rows e1, e2 = normal x e1, normal: the torus frame's axes in the world."""
        return np.stack([self.e1, np.cross(self.normal, self.e1), self.normal])

    def local(self, points: np.ndarray) -> np.ndarray:
        """Points (..., 3) in the torus frame (metres)."""
        return (np.asarray(points, float) - self.centre) @ self.basis.T

    def contains(self, points: np.ndarray, margin: float = 0.0, end_margin: float = 0.0) -> np.ndarray:
        """Whether points (..., 3) lie deeper than `margin` inside the tube, within the arc widened by
        `end_margin` metres along it at either end (the far side of the circle counts from the nearer end)."""
        q = self.local(points)
        a = np.arctan2(q[..., 1], q[..., 0])
        a = np.where(a < -0.5 * (2 * np.pi - self.angle), a + 2 * np.pi, a)
        reach = end_margin / self.bend_radius
        off = np.hypot(np.hypot(q[..., 0], q[..., 1]) - self.bend_radius, q[..., 2])
        return (a >= -reach) & (a <= self.angle + reach) & (off < self.radius - margin)

    def wall_exit(self, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Distance (n,) along unit `dirs` (n, 3) from `origin` (3,) to where each ray leaves the tube's wall
        within the arc (inf: nowhere ahead)."""
        o = self.local(origin) / self.bend_radius
        d = dirs @ self.basis.T
        roots = ray_torus(o, d.T, self.radius / self.bend_radius) * self.bend_radius  # (n, 4) ascending
        best = np.full(len(dirs), np.inf)
        for k in (1, 3):  # leaving the tube: the second root of each pair
            t = roots[:, k]
            p = o + (t / self.bend_radius)[:, None] * d
            ang = np.mod(np.arctan2(p[:, 1], p[:, 0]), 2 * np.pi)
            ok = np.isfinite(t) & (t > 0) & (ang <= self.angle)
            best = np.where(ok & (t < best), t, best)
        return best

    def holds_segment(self, X: np.ndarray, P: np.ndarray, tol: float) -> np.ndarray:
        """(n,) whether the segments X -> P (n, 3 each) lie inside the solid widened by `tol`, for a sufficient
        reason: both ends inside and the segment nowhere nearer the torus's axis line than the bend radius. The
        distance from that line is convex along a segment and the height linear, so on the outer side of the
        circle the distance from it, hypot(s - R, z), is convex too: at most its ends'; the arc's wedge (angle
        below pi) is convex."""
        a, b = self.local(X)[:, :2], self.local(P)[:, :2]
        d = b - a
        dd = np.einsum("ij,ij->i", d, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.clip(np.where(dd > 0, -np.einsum("ij,ij->i", a, d) / dd, 0.0), 0.0, 1.0)
        nearest = np.linalg.norm(a + t[:, None] * d, axis=1)
        return (nearest >= self.bend_radius) & self.contains(X, -tol, tol) & self.contains(P, -tol, tol)

    def solid_exit(self, X: np.ndarray, D: np.ndarray, tol: float) -> np.ndarray:
        """Line parameter tau >= 0 (n,) at which X + tau D (n, 3 each) leaves the solid widened by `tol` (the
        tube's radius, and the arc's end planes along it); 0 where X is outside it."""
        q = self.local(X)
        v = D @ self.basis.T
        speed = np.linalg.norm(v, axis=1)
        unit = v / np.where(speed > 0, speed, 1.0)[:, None]
        roots = ray_torus((q / self.bend_radius).T, unit.T, (self.radius + tol) / self.bend_radius)
        # real roots come first, in (entry, exit) pairs: the line leaves at the first exit root not behind X (on
        # the wall, X's own exit root may be a rounding error below 0: it leaves there, not at the next exit)
        with np.errstate(invalid="ignore"):
            exits = roots[:, 1::2]
            ahead = np.where(np.isfinite(exits) & (exits > -1e-9), exits, np.inf).min(axis=1)
        tau = np.maximum(ahead, 0.0) * self.bend_radius / np.where(speed > 0, speed, np.inf)
        # the wedge between the end planes: y >= -tol at the start, x sin(angle) - y cos(angle) >= -tol at the end
        sa, ca = np.sin(self.angle), np.cos(self.angle)
        for f, df in ((q[:, 1], v[:, 1]), (q[:, 0] * sa - q[:, 1] * ca, v[:, 0] * sa - v[:, 1] * ca)):
            with np.errstate(divide="ignore", invalid="ignore"):
                tau = np.minimum(tau, np.where(df < 0, (-tol - f) / df, np.inf))
        inside = self.contains(X, -tol, tol)
        return np.where(inside, np.maximum(tau, 0.0), 0.0)


def torus_coordinates(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(theta, radial, z) of points (..., 3) in the torus frame: the angle about the z axis from +x, the
    distance from the z axis and the height above the circle's plane."""
    p = np.asarray(points, float)
    return np.arctan2(p[..., 1], p[..., 0]), np.hypot(p[..., 0], p[..., 1]), p[..., 2]


def tube_distance(points: np.ndarray, bend_radius: float = 1.0) -> np.ndarray:
    """Distance of points (..., 3) in the torus frame to the full circle of radius `bend_radius` about z."""
    _, rho, z = torus_coordinates(points)
    return np.hypot(rho - bend_radius, z)
