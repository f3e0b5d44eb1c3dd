"""The two-cylinder T-intersection model (fisheye paper III-D, eq. 7-8, Fig. 4b).

Two cylinders of the same radius r whose axes meet at one point I. The red cylinder C_r is given
by its eq. 4 parameters (gamma, beta, t_X, t_Y) relative to the red section's end pose P_r, the
blue one C_b relative to the blue section's end pose P_b (`pipemap.geometry.cylinder`: C maps
the reference camera's frame to the cylinder frame, whose z axis is the cylinder axis oriented
along the camera's optical axis and whose origin O(C) is the foot of the camera centre on the
axis). The tee's parameters Phi = (zeta_r, l_r, zeta_b, l_b, phi) fix the change of pose Q between
P_b and P_r, with

    A_r = [R_Z(zeta_r) | (0, 0, l_r)^T],   A_b = [R_Z(zeta_b) R_Y(phi) | (0, 0, l_b)^T]
    D = p(inv(A_r), inv(A_b)) = inv(A_r) inv(A_b)                                        (eq. 7)
    Q = p(inv(C_r), p(D, C_b)) = inv(C_r) D C_b                                           (eq. 8)

where p(b, a) is a followed by b and [R | t] acts as X -> R X + t. Which frame maps to which:

    A_r : red cylinder frame  -> tee frame (origin I, z along the red axis)
    A_b : tee frame           -> blue cylinder frame
    D   : blue cylinder frame -> red cylinder frame
    Q   : P_b's camera frame  -> P_r's camera frame, so that T_wc(P_b) = T_wc(P_r) Q.

Eq. 7 taken literally, D = A_r A_b, would put O(C_b) on the red axis (l_r and l_b would only appear
as l_r + l_b); the factors are therefore the two halves of the red -> blue chain and D, the blue ->
red map that eq. 8 composes, is their inverse. With this reading the paper's description holds:
zeta_r turns about the red axis, zeta_b about the blue axis, phi is the angle between the two
axes (in [0, 180) deg: 0 is straight on, 90 deg a square turn), and

    I = O(C_r) - l_r z_r = O(C_b) + l_b z_b,

z_r, z_b being the unit axis directions (oriented along P_r's and P_b's optical axes), so l_r is
the signed distance of O(C_r) from I along z_r and -l_b that of O(C_b) along z_b. For a camera
that drives from the red section into the blue one, both are negative.

The blue cylinder's place in the world is T_wc(P_r) inv(C_r) D: it depends on Phi and the red side
only; C_b sets where P_b sits relative to the blue axis.

Jacobians are with respect to the right perturbation of `pipemap.geometry.se3`: a pose T moves to
T exp(delta), delta = (rho, phi) in T's own axes. Every transform here is a product of elementary
rotations about and translations along coordinate axes, each linear in one parameter, so the
derivatives come from one generic chain rule (`_Chain`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.errors import PipemapError
from pipemap.geometry.cylinder import Cylinder, local_frame, rot_x, rot_y, rot_z
from pipemap.geometry.rotations import skew
from pipemap.geometry.se3 import as_rt, compose, invert, to_matrix, world_to_camera

_ROT, _TRANS = "R", "T"
_AXES = np.eye(3)
_ROTATIONS = (rot_x, rot_y, rot_z)

# The full parameter vector of the chains: Phi (5), then C_r (4), then C_b (4).
ZETA_R, L_R, ZETA_B, L_B, PHI = range(5)
_RED = (5, 6, 7, 8)  # gamma_r, beta_r, t_X r, t_Y r
_BLUE = (9, 10, 11, 12)


def _cylinder_factors(idx, sign: int):
    """C = Trans(t_X, t_Y, 0) Rot_X(gamma) Rot_Y(beta) (sign +1) or its inverse (sign -1)."""
    g, b, tx, ty = idx
    forward = [(_TRANS, 0, 1, tx), (_TRANS, 1, 1, ty), (_ROT, 0, 1, g), (_ROT, 1, 1, b)]
    return forward if sign > 0 else [(k, a, -1, v) for k, a, _, v in reversed(forward)]


# inv(A_r) = Rot_Z(-zeta_r) Trans(-l_r e_z); inv(A_b) = Rot_Y(-phi) Rot_Z(-zeta_b) Trans(-l_b e_z).
_D_FACTORS = [(_ROT, 2, -1, ZETA_R), (_TRANS, 2, -1, L_R), (_ROT, 1, -1, PHI), (_ROT, 2, -1, ZETA_B),
              (_TRANS, 2, -1, L_B)]
_Q_FACTORS = _cylinder_factors(_RED, -1) + _D_FACTORS + _cylinder_factors(_BLUE, +1)
# inv(D) C_r = A_b A_r C_r: P_r's camera frame -> blue cylinder frame.
_BLUE_FROM_RED_CAMERA = ([(_TRANS, 2, 1, L_B), (_ROT, 2, 1, ZETA_B), (_ROT, 1, 1, PHI), (_TRANS, 2, 1, L_R),
                          (_ROT, 2, 1, ZETA_R)] + _cylinder_factors(_RED, +1))


class _Chain:
    """A product G_1 G_2 ... G_n of elementary transforms, each a rotation about or a translation along
    a coordinate axis by coef * x[var]."""

    def __init__(self, factors, x: np.ndarray):
        self.factors = factors
        self.R, self.t = [], []
        for kind, axis, coef, var in factors:
            v = coef * x[var]
            if kind == _ROT:
                self.R.append(_ROTATIONS[axis](v))
                self.t.append(np.zeros(3))
            else:
                self.R.append(np.eye(3))
                self.t.append(v * _AXES[axis])

    def product(self) -> tuple[np.ndarray, np.ndarray]:
        R, t = np.eye(3), np.zeros(3)
        for Rk, tk in zip(self.R, self.t):
            R, t = compose(R, t, Rk, tk)
        return R, t

    def pose_jacobian(self, n_vars: int) -> np.ndarray:
        """d delta / d x (6, n_vars) for the right perturbation of the product: perturbing G_k on its
        right by xi moves the product by Ad(inv(G_{k+1} ... G_n)) xi on its right."""
        J = np.zeros((6, n_vars))
        S_R, S_t = np.eye(3), np.zeros(3)  # suffix G_{k+1} ... G_n
        for k in reversed(range(len(self.factors))):
            kind, axis, coef, var = self.factors[k]
            xi = np.zeros(6)
            xi[(3 if kind == _ROT else 0) + axis] = coef
            J[:, var] += _adjoint_of_inverse(S_R, S_t) @ xi
            S_R, S_t = compose(self.R[k], self.t[k], S_R, S_t)
        return J

    def apply(self, points: np.ndarray, n_vars: int | None = None):
        """The product applied to points (M, 3); with n_vars also d result / d x (M, 3, n_vars)."""
        P = np.asarray(points, float)
        suffix = [P]
        for Rk, tk in zip(reversed(self.R), reversed(self.t)):
            suffix.append(suffix[-1] @ Rk.T + tk)
        out = suffix[-1]
        if n_vars is None:
            return out
        J = np.zeros(P.shape[:-1] + (3, n_vars))
        prefix = np.eye(3)  # rotation of G_1 ... G_k
        for k, (kind, axis, coef, var) in enumerate(self.factors):
            prefix = prefix @ self.R[k]
            if kind == _ROT:
                v = suffix[len(self.factors) - 1 - k]  # G_{k+1} ... G_n applied to the points
                d = coef * np.cross(_AXES[axis], v)
            else:
                d = np.broadcast_to(coef * _AXES[axis], P.shape)
            J[..., :, var] += d @ prefix.T
        return out, J


def _adjoint_of_inverse(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Ad(inv(Z)) for Z = (R, t), in the (rho, phi) order: inv(Z) exp(xi) Z = exp(Ad(inv(Z)) xi)."""
    A = np.zeros((6, 6))
    A[:3, :3] = R.T
    A[:3, 3:] = -R.T @ skew(t)
    A[3:, 3:] = R.T
    return A


def adjoint_of_inverse(T) -> np.ndarray:
    """Ad(inv(T)) (6, 6) of a 4x4 pose or (R, t): T_a T moved on the right of T_a by xi equals T_a T
    moved on its own right by Ad(inv(T)) xi -- how a camera attached at T to a moving pose moves."""
    R, t = as_rt(T)
    return _adjoint_of_inverse(R, t)


def _wrap(a):
    return (np.asarray(a, float) + np.pi) % (2 * np.pi) - np.pi


@dataclass(frozen=True)
class TeeModel:
    """Phi = (zeta_r, l_r, zeta_b, l_b, phi) with the red and blue cylinders' eq. 4 parameters relative to
    P_r and P_b, and the common radius; see the module docstring for the conventions."""

    params: np.ndarray  # (5,) zeta_r, l_r, zeta_b, l_b, phi (radians, metres)
    red: np.ndarray  # (4,) gamma, beta, t_X, t_Y of C_r relative to P_r
    blue: np.ndarray  # (4,) ... of C_b relative to P_b
    radius: float

    def __post_init__(self):
        for name, n in (("params", 5), ("red", 4), ("blue", 4)):
            v = np.array(getattr(self, name), dtype=float).reshape(-1)
            if v.shape != (n,) or not np.all(np.isfinite(v)):
                raise ValueError(f"tee {name} must be {n} finite numbers, got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        r = float(self.radius)
        if not np.isfinite(r) or r <= 0:
            raise PipemapError(f"pipe radius must be a positive number of metres, got {self.radius!r}")
        object.__setattr__(self, "radius", r)

    @property
    def vector(self) -> np.ndarray:
        """Phi, C_r and C_b as one 13-vector (the order of the `*_jacobian` columns)."""
        return np.concatenate([self.params, self.red, self.blue])

    @property
    def angle_deg(self) -> float:
        return float(np.degrees(self.params[PHI]))

    def with_params(self, params) -> "TeeModel":
        return TeeModel(params, self.red, self.blue, self.radius)

    def canonical(self) -> "TeeModel":
        """The same tee with phi in [0, pi) and the zetas in [-pi, pi): R_Y(-phi) = R_Z(pi) R_Y(phi) R_Z(-pi),
        so (zeta_r, zeta_b, phi) and (zeta_r + pi, zeta_b - pi, -phi) are one tee."""
        zr, lr, zb, lb, phi = self.params
        phi = float(_wrap(phi))
        if phi < 0:
            zr, zb, phi = zr + np.pi, zb - np.pi, -phi
        return self.with_params([_wrap(zr), lr, _wrap(zb), lb, phi])

    # -- eq. 7-8 ----------------------------------------------------------------------------

    def D(self) -> np.ndarray:
        """Eq. 7: the blue cylinder frame -> red cylinder frame transform (4x4)."""
        return to_matrix(*_Chain(_D_FACTORS, self.vector).product())

    def Q(self) -> np.ndarray:
        """Eq. 8: P_b's camera frame -> P_r's camera frame (4x4), i.e. T_wc(P_b) = T_wc(P_r) Q."""
        return to_matrix(*_Chain(_Q_FACTORS, self.vector).product())

    def q_jacobian(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """d delta_Q / d Phi (6, 5), / d C_r (6, 4), / d C_b (6, 4), delta_Q being Q's right perturbation
        (also P_b's, while P_r is held)."""
        J = _Chain(_Q_FACTORS, self.vector).pose_jacobian(13)
        return J[:, :5], J[:, list(_RED)], J[:, list(_BLUE)]

    def blue_pose(self, red_pose) -> np.ndarray:
        """T_wc of P_b (4x4) given T_wc of P_r."""
        return to_matrix(*as_rt(red_pose)) @ self.Q()

    # -- the intersection and the cylinders ---------------------------------------------------

    def intersection(self, red_pose=None) -> np.ndarray:
        """I in P_r's camera frame or, given T_wc of P_r, in the world."""
        Rc, tc = local_frame(self.red)
        I_ref = Rc.T @ (np.array([0.0, 0.0, -self.params[L_R]]) - tc)
        if red_pose is None:
            return I_ref
        R, t = as_rt(red_pose)
        return R @ I_ref + t

    def red_cylinder(self, red_pose) -> Cylinder:
        R, t = as_rt(red_pose)
        return Cylinder.from_local(self.red, R, t, self.radius)

    def blue_cylinder(self, red_pose) -> Cylinder:
        """The blue cylinder in the world: frame T_wc(P_r) inv(C_r) D."""
        R, t = as_rt(red_pose)
        Rc, tc = local_frame(self.red)
        R_cr, t_cr = compose(R, t, *invert(Rc, tc))
        R_wb, t_wb = compose(R_cr, t_cr, *as_rt(self.D()))
        return Cylinder(t_wb, R_wb[:, 2], self.radius)

    def axial(self, points, red_pose) -> tuple[np.ndarray, np.ndarray]:
        """Signed coordinates (a_r, a_b) of world points from I along the red and the blue axis (z_r, z_b)."""
        R, t = as_rt(red_pose)
        v = np.asarray(points, float) - self.intersection((R, t))
        return v @ self.red_cylinder((R, t)).direction, v @ self.blue_cylinder((R, t)).direction

    def distances(self, points, red_pose, jacobians: bool = True):
        """Signed distances of world points to the red and the blue wall.

        Returns d_red (M,), d_blue (M,) and, with jacobians, d d_red / d X (M, 3), d d_blue / d X (M, 3)
        and d d_blue / d Phi (M, 5) (P_r and C_r held; d_red does not depend on Phi).
        """
        R, t = as_rt(red_pose)
        Xr = world_to_camera(R, t, np.asarray(points, float))
        Rc, tc = local_frame(self.red)
        Xt = Xr @ Rc.T + tc
        rho_r = np.hypot(Xt[:, 0], Xt[:, 1])
        chain = _Chain(_BLUE_FROM_RED_CAMERA, self.vector)
        if not jacobians:
            Xb = chain.apply(Xr)
            return rho_r - self.radius, np.hypot(Xb[:, 0], Xb[:, 1]) - self.radius
        Xb, J = chain.apply(Xr, 13)
        rho_b = np.hypot(Xb[:, 0], Xb[:, 1])
        n_r = np.column_stack([Xt[:, :2] / np.where(rho_r > 0, rho_r, 1.0)[:, None], np.zeros(len(Xt))])
        n_b = np.column_stack([Xb[:, :2] / np.where(rho_b > 0, rho_b, 1.0)[:, None], np.zeros(len(Xb))])
        Jr_X = n_r @ Rc @ R.T
        Rb = chain.product()[0]  # P_r camera -> blue cylinder rotation
        Jb_X = n_b @ Rb @ R.T
        Jb_phi = np.einsum("mi,mij->mj", n_b, J[:, :, :5])
        return rho_r - self.radius, rho_b - self.radius, Jr_X, Jb_X, Jb_phi

    # -- initialisers -------------------------------------------------------------------------

    @classmethod
    def from_poses(cls, red_pose, blue_pose, red, blue, radius: float) -> "TeeModel":
        """Phi from approximately placed P_r and P_b (T_wc) and the cylinders' parameters relative to them.

        The blue cylinder frame seen from the red one, D0 = C_r inv(P_r) P_b inv(C_b), is matched by Phi:
        phi is the angle between the axes, the zetas turn the cylinder frames about their axes onto the
        plane of the two axes, and l_r, l_b put I at the closest approach of the two axes -- on the
        red axis for the red side and on the blue axis for the blue side, so if the axes miss each other
        the blue side moves across by their distance.
        """
        red, blue = np.asarray(red, float), np.asarray(blue, float)
        Rr, tr = as_rt(red_pose)
        Rb, tb = as_rt(blue_pose)
        R_rel, t_rel = compose(*invert(Rr, tr), Rb, tb)  # P_b -> P_r
        Rcr, tcr = local_frame(red)
        Rcb, tcb = local_frame(blue)
        R_D, t_D = compose(*compose(Rcr, tcr, R_rel, t_rel), *invert(Rcb, tcb))  # blue cyl -> red cyl
        d = R_D[:, 2]  # blue axis direction in the red cylinder frame; it passes through t_D
        c = d[2]
        phi = float(np.arccos(np.clip(c, -1.0, 1.0)))
        # Closest approach of the red axis (s e_z) and the blue axis (t_D + u d).
        denom = 1.0 - c * c
        if denom < 1e-12:  # parallel axes: any point of the red axis; take the foot of O(C_b)
            s, u = t_D[2], 0.0
        else:
            s = (t_D[2] - c * (t_D @ d)) / denom
            u = (c * t_D[2] - t_D @ d) / denom
        zeta_r = float(np.arctan2(d[1], -d[0])) if np.hypot(d[0], d[1]) > 1e-9 else 0.0
        M = rot_y(phi) @ rot_z(zeta_r) @ R_D  # = R_Z(-zeta_b)
        zeta_b = float(-np.arctan2(M[1, 0], M[0, 0]))
        return cls([zeta_r, -s, zeta_b, u, phi], red, blue, radius).canonical()

    @classmethod
    def initial(cls, red_cylinder: Cylinder, blue_cylinder: Cylinder, red_pose, blue_pose,
                radius: float | None = None) -> "TeeModel":
        """Phi from two world cylinders placed approximately (e.g. from chained odometry) and the poses
        they are parameterised against (the red section's last pose, the blue section's first)."""
        Rr, tr = as_rt(red_pose)
        Rb, tb = as_rt(blue_pose)
        r = red_cylinder.radius if radius is None else radius
        return cls.from_poses((Rr, tr), (Rb, tb), red_cylinder.local_params(Rr, tr),
                              blue_cylinder.local_params(Rb, tb), r)


__all__ = ["TeeModel", "adjoint_of_inverse"]
