"""Tori (an elbow's bent pipe): exact ray intersection and the distance to the wall, vectorised.

A torus here is the tube of minor radius `r` around a circle of radius `R` (the bend radius) about
the z axis in its own frame. Everything works in that frame with lengths divided by R, so that the
quartic's coefficients stay near 1 whatever the pipe's size.
"""

from __future__ import annotations

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
    radius 1 and tube radius `minor` about the z axis (its own frame, lengths in bend radii). `origin` (3,),
    `dirs` (3, N) unit vectors as components."""
    o = np.asarray(origin, float)
    dx, dy, dz = (np.asarray(v, float) for v in dirs)
    k = o[0] * dx + o[1] * dy + o[2] * dz
    m = float(o @ o) + 1.0 - minor * minor
    a = 4 * k
    b = 4 * k * k + 2 * m - 4 * (dx * dx + dy * dy)
    c = 4 * k * m - 8 * (o[0] * dx + o[1] * dy)
    d = np.full_like(k, m * m - 4 * (o[0] ** 2 + o[1] ** 2))
    return np.sort(quartic_real_roots(a, b, c, d), axis=-1)


def torus_coordinates(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(theta, radial, z) of points (..., 3) in the torus frame: the angle about the z axis from +x, the
    distance from the z axis and the height above the circle's plane."""
    p = np.asarray(points, float)
    return np.arctan2(p[..., 1], p[..., 0]), np.hypot(p[..., 0], p[..., 1]), p[..., 2]


def tube_distance(points: np.ndarray, bend_radius: float = 1.0) -> np.ndarray:
    """Distance of points (..., 3) in the torus frame to the full circle of radius `bend_radius` about z."""
    _, rho, z = torus_coordinates(points)
    return np.hypot(rho - bend_radius, z)
