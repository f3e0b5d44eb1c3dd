"""Straight cylinders of known radius: distance, ray intersection, the fisheye paper's 4-DOF local
parameterisation (eq. 4-5) and a robust fit to 3D points.

Local parameterisation (fisheye paper III-C, eq. 4-5). A cylinder is expressed relative to a
reference camera pose P_m = [R_m | t_m] (world -> camera; here the reference is given as the
camera-to-world pose T_wc = (R, c) of that camera, so R_m = R^T and t_m = -R^T c). With the
parameters p = (gamma, beta, t_X, t_Y),

    C = [R~ | t~] = [R_X(gamma) R_Y(beta) | (t_X, t_Y, 0)^T]                          (eq. 4)
    X~ = R~ (R_m X + t_m) + t~                                                        (eq. 5)

maps a world point X into the cylinder frame, whose z axis is the cylinder axis, so the signed
distance of X from the wall is sqrt(X~^2 + Y~^2) - r (eq. 6 squares it). In the reference camera's
frame the axis direction is R~^T e_z = (-sin b cos g, sin g, cos b cos g), i.e. gamma = beta = 0 is an
axis along the optical axis -- natural for a camera looking down the pipe, and the parameterisation
is singular only for an axis perpendicular to the optical axis (gamma = +-90 deg). The cylinder
frame's origin O(C) (X~ = 0) is the foot of the reference camera centre on the axis: the point the
T-intersection model (III-D, eq. 7-8) measures its offsets l_r, l_b from.

Signs: the signed distance is positive outside the wall (beyond it, seen from inside the pipe) and
negative inside the pipe.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.errors import PipemapError
from pipemap.geometry.bend import AxisKnots, bent_distance
from pipemap.geometry.rotations import look_rotation
from pipemap.geometry.se3 import camera_point_jacobian, world_to_camera
from pipemap.solvers import huber_irls, levenberg_marquardt, mad_inliers

_EX, _EY, _EZ = np.eye(3)


def rot_x(a) -> np.ndarray:
    """R_X(a), vectorised over the shape of a."""
    a = np.asarray(a, float)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(a) -> np.ndarray:
    a = np.asarray(a, float)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(a) -> np.ndarray:
    a = np.asarray(a, float)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def local_frame(params) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4: p = (gamma, beta, t_X, t_Y) -> (R~, t~), the reference-camera -> cylinder transform."""
    g, b, tx, ty = np.asarray(params, float)
    return rot_x(g) @ rot_y(b), np.array([tx, ty, 0.0])


def _check_radius(radius) -> float:
    r = float(radius)
    if not np.isfinite(r) or r <= 0:
        raise PipemapError(f"pipe radius must be a positive number of metres, got {radius!r}")
    return r


def local_distance(points_ref, params, radius: float, jacobians: bool = True, knots: AxisKnots | None = None):
    """Signed distance of points given in the reference camera's frame (X_m = R_m X + t_m).

    params is (gamma, beta, t_X, t_Y), followed with `knots` by the bent axis's offsets (K, 2) in the
    cylinder frame's x and y (`pipemap.geometry.bend`). Returns d (M,) and, with jacobians,
    d d / d X_m (M, 3) and d d / d params (M, 4 + 2 K).
    """
    Xm = np.asarray(points_ref, float)
    p = np.asarray(params, float)
    g, b = float(p[0]), float(p[1])
    Rx, Ry = rot_x(g), rot_y(b)
    Rt, tt = local_frame(p[:4])
    Xt = Xm @ Rt.T + tt
    offsets = None if knots is None else p[4:].reshape(len(knots), 2)
    d, n, i, f = bent_distance(Xt[:, :2], Xt[:, 2], knots, offsets, radius)
    if not jacobians:
        return d
    J_x = n @ Rt
    J_p = np.empty((len(Xm), len(p)))
    v = Xt - tt  # R_X R_Y X_m
    # d R_X / d gamma = [e_x]x R_X:  n . (e_x x v) = n_z v_y - n_y v_z
    J_p[:, 0] = n[:, 2] * v[:, 1] - n[:, 1] * v[:, 2]
    # R_X [e_y]x R_Y X_m:  (n R_X) . (e_y x Y) = m_x Y_z - m_z Y_x, Y = R_Y X_m
    m = n @ Rx
    Y = Xm @ Ry.T
    J_p[:, 1] = m[:, 0] * Y[:, 2] - m[:, 2] * Y[:, 0]
    J_p[:, 2] = n[:, 0]
    J_p[:, 3] = n[:, 1]
    J_p[:, 4:] = 0.0
    if knots is not None:
        rows = np.arange(len(Xm))
        for c in range(2):
            J_p[rows, 4 + 2 * i + c] -= (1.0 - f) * n[:, c]
            J_p[rows, 4 + 2 * (i + 1) + c] -= f * n[:, c]
    return d, J_x, J_p


def distance_jacobians(points, params, ref_R, ref_t, radius: float, knots: AxisKnots | None = None):
    """Signed distance of world points to the cylinder `params` relative to the reference pose T_wc = (ref_R, ref_t).

    Returns d (M,), d d / d X (M, 3), d d / d params (M, 4 [+ 2 K]) and d d / d reference pose (M, 6)
    under the right perturbation of `pipemap.geometry.se3` (for models where the reference pose itself is free).
    """
    Xm = world_to_camera(ref_R, ref_t, np.asarray(points, float))
    d, J_xm, J_p = local_distance(Xm, params, radius, knots=knots)
    J_X = J_xm @ np.asarray(ref_R).T
    J_ref = np.einsum("mi,mij->mj", J_xm, camera_point_jacobian(Xm))
    return d, J_X, J_p, J_ref


@dataclass(frozen=True)
class Cylinder:
    """A straight cylinder in world coordinates: a point on the axis, the unit axis direction, the radius."""

    origin: np.ndarray
    direction: np.ndarray
    radius: float

    def __post_init__(self):
        o = np.asarray(self.origin, float).reshape(3)
        d = np.asarray(self.direction, float).reshape(3)
        n = np.linalg.norm(d)
        if not (np.all(np.isfinite(o)) and np.isfinite(n) and n > 0):
            raise ValueError("cylinder origin and direction must be finite, with a non-zero direction")
        object.__setattr__(self, "origin", o)
        object.__setattr__(self, "direction", d / n)
        object.__setattr__(self, "radius", _check_radius(self.radius))

    # -- local parameterisation (eq. 4-5) ---------------------------------------------------

    @classmethod
    def from_local(cls, params, ref_R, ref_t, radius: float) -> "Cylinder":
        """The cylinder of local parameters (gamma, beta, t_X, t_Y) relative to the reference pose T_wc."""
        Rt, tt = local_frame(params)
        axis_m, origin_m = Rt.T @ _EZ, -Rt.T @ tt
        ref_R = np.asarray(ref_R, float)
        return cls(ref_R @ origin_m + np.asarray(ref_t, float), ref_R @ axis_m, radius)

    def local_params(self, ref_R, ref_t) -> np.ndarray:
        """(gamma, beta, t_X, t_Y) relative to the reference pose T_wc; the axis is oriented to +z of that camera."""
        ref_R = np.asarray(ref_R, float)
        a = ref_R.T @ self.direction
        if a[2] < 0:
            a = -a
        if a[2] < 1e-9 and abs(a[1]) > 1 - 1e-12:
            raise ValueError("the cylinder axis is perpendicular to the reference camera's optical axis "
                             "(gamma = 90 deg)")
        g, b = np.arcsin(np.clip(a[1], -1.0, 1.0)), np.arctan2(-a[0], a[2])
        Rt = rot_x(g) @ rot_y(b)
        o = Rt @ world_to_camera(ref_R, ref_t, self.origin)
        return np.array([g, b, -o[0], -o[1]])

    # -- geometry ---------------------------------------------------------------------------

    def axial(self, points) -> np.ndarray:
        """Signed coordinate of points along the axis, from `origin`."""
        return (np.asarray(points, float) - self.origin) @ self.direction

    def distance(self, points) -> np.ndarray:
        """Signed distance to the wall: |distance from the axis| - r (positive beyond the wall)."""
        return self.distance_jacobian(points)[0]

    def distance_jacobian(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (...,) and its derivative with respect to the point (..., 3)."""
        v = np.asarray(points, float) - self.origin
        radial = v - (v @ self.direction)[..., None] * self.direction
        rho = np.linalg.norm(radial, axis=-1)
        return rho - self.radius, radial / np.where(rho > 0, rho, 1.0)[..., None]

    def intersect(self, origins, directions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where rays origin + s * direction (s > 0) first meet the wall.

        For a camera inside the pipe this is the one exit point, for any bearing -- also those more
        than 90 deg off the optical axis (the maths is in world coordinates and never divides by the
        bearing's z). Returns points (..., 3), s (...) and valid (...): False for rays parallel to
        the axis or, from outside, rays that miss.
        """
        o = np.asarray(origins, float)
        b = np.asarray(directions, float)
        w = o - self.origin
        w_p = w - (w @ self.direction)[..., None] * self.direction
        b_p = b - (b @ self.direction)[..., None] * self.direction
        A = np.sum(b_p * b_p, -1)
        B = np.sum(w_p * b_p, -1)
        C = np.sum(w_p * w_p, -1) - self.radius**2
        disc = B * B - A * C
        ok = (A > 1e-14 * np.maximum(np.sum(b * b, -1), 1e-300)) & (disc >= 0)
        sq = np.sqrt(np.where(ok, disc, 0.0))
        q = -(B + np.where(B >= 0, sq, -sq))  # stable pair of roots q / A and C / q
        q = np.where(q == 0, -1e-300, q)
        r1 = np.where(ok, q / np.where(ok, A, 1.0), np.nan)
        r2 = np.where(ok, C / q, np.nan)
        big = np.inf
        s = np.minimum(np.where(r1 > 0, r1, big), np.where(r2 > 0, r2, big))
        valid = ok & np.isfinite(s)
        s = np.where(valid, s, np.nan)
        return o + s[..., None] * b, s, valid


    def intersect_bearings(self, R, t, bearings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`intersect` for unit bearings (..., 3) in the frame of the camera T_wc = (R, t) (e.g. from
        `camera.unproject`); returns world points, ranges along the bearings and validity."""
        b = np.asarray(bearings, float) @ np.asarray(R, float).T
        return self.intersect(np.broadcast_to(np.asarray(t, float), b.shape), b)


# -- robust fit with a known radius ------------------------------------------------------------


@dataclass(frozen=True)
class CylinderFit:
    cylinder: Cylinder
    params: np.ndarray  # (gamma, beta, t_X, t_Y) relative to `reference`
    reference: tuple[np.ndarray, np.ndarray]  # T_wc = (R, t) the parameters are relative to
    inliers: np.ndarray  # (M,) bool
    rms: float  # RMS signed distance of the inliers (m)
    free_radius: float  # radius of the same data fitted with the radius free: radius / free_radius ~ scale error
    iterations: int
    # (4, 4) of `params`: rms^2 (J^T J)^-1 over the inliers, as if the points' distances were independent
    covariance: np.ndarray | None = None


def foremost(centres: np.ndarray) -> int:
    """Index of the camera centre (N, 3) farthest from the first: the last one unless the robot turned back on
    the way, when where it ended says nothing of the pipe's direction (it drove on and came back)."""
    c = np.asarray(centres, float)
    return int(np.argmax(np.linalg.norm(c - c[0], axis=1)))


def path_chord(centres: np.ndarray) -> np.ndarray:
    """The camera path's extent along the pipe: from its first centre (N, 3) to the one farthest from it."""
    c = np.asarray(centres, float)
    return c[foremost(c)] - c[0]


def axis_frame(direction: np.ndarray) -> np.ndarray:
    """A rotation whose z axis is `direction`."""
    hint = _EY if abs(direction @ _EY) < 0.9 else _EX
    return look_rotation(direction, hint)


def _robust_lm(fun, p, huber: float, iterations: int):
    """Minimise sum huber(r_i(p)) on a handful of parameters: (p, iterations used)."""
    out = levenberg_marquardt(fun, lambda q, d: q + d, p, iterations=iterations, cost=huber_irls(huber))
    return out.state, out.iterations


def fit_cylinder(points, radius: float, *, reference=None, direction=None, huber: float = 0.005,
                 mad_k: float = 3.0, outlier_passes: int = 2, iterations: int = 50) -> CylinderFit:
    """Robust fit of a cylinder of known radius to points on its wall.

    The axis direction starts from `direction` (e.g. the camera path's) or, without one, from the
    principal axis of the points (right when the points span more than ~2.5 radii along the pipe).
    The axis position starts from an algebraic circle fit of the points projected along that direction.
    A Huber-weighted LM with the radius free then settles the axis (its radius is `free_radius`), and a
    second one with the radius fixed gives the result, with MAD rejection of points off the wall
    (threshold max(mad_k * 1.4826 * MAD, huber)). Parameters are relative to `reference` (T_wc (R, t) or
    a 4x4), by default a frame at the points' centroid with z along the initial direction.
    """
    P = np.asarray(points, float)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must be (M, 3), got {P.shape}")
    r = _check_radius(radius)
    keep = np.all(np.isfinite(P), axis=1)
    if keep.sum() < 5:
        raise ValueError(f"a cylinder fit needs at least 5 finite points, got {int(keep.sum())}")
    centroid = P[keep].mean(axis=0)
    if direction is None:
        cov = np.cov((P[keep] - centroid).T)
        direction = np.linalg.eigh(cov)[1][:, -1]
    d0 = np.asarray(direction, float) / np.linalg.norm(direction)
    if reference is None:
        ref_R, ref_t = axis_frame(d0), centroid
    elif isinstance(reference, (tuple, list)):
        ref_R, ref_t = (np.asarray(x, float) for x in reference)
    else:
        T = np.asarray(reference, float)
        ref_R, ref_t = T[:3, :3], T[:3, 3]
    Xm = world_to_camera(ref_R, ref_t, P)
    # Start: axis along d0 through the centre of an algebraic (Kasa) circle fit.
    p = Cylinder(ref_t, d0, r).local_params(ref_R, ref_t)
    Y = Xm[keep] @ local_frame(p)[0].T
    A = np.column_stack([2 * Y[:, 0], 2 * Y[:, 1], np.ones(len(Y))])
    rhs = Y[:, 0] ** 2 + Y[:, 1] ** 2
    (a, b, c), *_ = np.linalg.lstsq(A, rhs, rcond=None)
    p[2:] = [-a, -b]
    r_free = float(np.sqrt(max(c + a * a + b * b, 1e-12)))

    def free(q, idx):
        d, _, J_p = local_distance(Xm[idx], q[:4], q[4])
        return d, np.column_stack([J_p, -np.ones(len(d))])

    q, it_total = _robust_lm(lambda q: free(q, keep), np.append(p, r_free), huber, iterations)
    p, r_free = q[:4], float(q[4])

    inliers = keep.copy()
    for pass_ in range(outlier_passes + 1):
        p, it = _robust_lm(lambda q: local_distance(Xm[inliers], q, r)[::2], p, huber, iterations)
        it_total += it
        if pass_ == outlier_passes:
            break
        d = local_distance(Xm, p, r, jacobians=False)
        new = keep & mad_inliers(np.where(keep, d, 0.0), mad_k, inliers, huber)
        if np.array_equal(new, inliers) or new.sum() < 5:
            break
        inliers = new
    d, _, J = local_distance(Xm[inliers], p, r)
    rms = float(np.sqrt(np.mean(d**2)))
    cyl = Cylinder.from_local(p, ref_R, ref_t, r)
    return CylinderFit(cyl, p, (ref_R, ref_t), inliers, rms, abs(r_free), it_total, rms**2 * np.linalg.pinv(J.T @ J))


__all__ = ["Cylinder", "CylinderFit", "axis_frame", "fit_cylinder", "local_frame", "local_distance",
           "distance_jacobians", "rot_x", "rot_y", "rot_z"]
