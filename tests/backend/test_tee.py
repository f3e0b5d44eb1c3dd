"""The two-cylinder tee model (fisheye paper eq. 7-8) on constructed configurations with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.errors import PipemapError
from pipemap.geometry.cylinder import Cylinder
from pipemap.geometry.rotations import exp_so3, log_so3, look_rotation
from pipemap.geometry.se3 import as_rt, to_matrix
from pipemap.geometry.tee import TeeModel, adjoint_of_inverse

RADIUS = 0.2
G = exp_so3(np.array([0.4, -0.3, 0.7]))  # the constructed scene is placed anywhere in the world
g = np.array([2.0, -1.0, 0.5])


def constructed_tee(angle_deg: float):
    """P_r 0.45 m before I on the red axis, P_b 0.3 m after it on the blue axis, both off-axis and tilted.

    The red axis runs along x through I = g (after the placement G), the blue axis leaves I at angle_deg
    from the red one in the xy plane. Returns I, the axis directions, T_wc of P_r and P_b, the world cylinders.
    """
    a = np.radians(angle_deg)
    z_r, z_b = G @ np.array([1.0, 0, 0]), G @ np.array([np.cos(a), np.sin(a), 0.0])
    up = G @ np.array([0, 0, 1.0])
    I = g.copy()
    R_r = look_rotation(z_r, up) @ exp_so3(np.array([0.03, -0.02, 0.2]))
    t_r = I - 0.45 * z_r + G @ np.array([0.0, 0.03, -0.05])
    R_b = look_rotation(z_b, up) @ exp_so3(np.array([-0.04, 0.05, -0.3]))
    t_b = I + 0.3 * z_b + 0.02 * np.cross(z_b, up) - 0.04 * up
    return I, z_r, z_b, (R_r, t_r), (R_b, t_b), Cylinder(I, z_r, RADIUS), Cylinder(I, z_b, RADIUS)


def foot(cyl: Cylinder, p):
    return cyl.origin + cyl.axial(p) * cyl.direction


@pytest.mark.parametrize("angle", [90.0, 60.0, 135.0])
def test_phi_of_a_constructed_tee_reproduces_it(angle):
    I, z_r, z_b, Pr, Pb, Cr, Cb = constructed_tee(angle)
    tee = TeeModel.initial(Cr, Cb, Pr, Pb)
    zr, lr, zb, lb, phi = tee.params
    assert np.degrees(phi) == pytest.approx(angle, abs=1e-9)
    # l_r, l_b: signed distances of the cylinder origins (feet of the camera centres) from I.
    O_r, O_b = foot(Cr, Pr[1]), foot(Cb, Pb[1])
    assert lr == pytest.approx((O_r - I) @ z_r, abs=1e-12) and lr == pytest.approx(-0.45, abs=1e-12)
    assert lb == pytest.approx((I - O_b) @ z_b, abs=1e-12) and lb == pytest.approx(-0.3, abs=1e-12)
    # Q maps P_r to P_b exactly, and I is where both axes meet.
    T_b = tee.blue_pose(Pr)
    assert np.abs(T_b - to_matrix(*Pb)).max() < 1e-12
    assert np.abs(tee.intersection(Pr) - I).max() < 1e-12
    assert abs(Cr.distance(I) + RADIUS) < 1e-12 and abs(Cb.distance(I) + RADIUS) < 1e-12
    # The blue cylinder placed by Phi from the red side alone is the true one.
    blue = tee.blue_cylinder(Pr)
    assert abs(blue.direction @ z_b) == pytest.approx(1.0, abs=1e-12)
    assert np.linalg.norm(np.cross(blue.origin - I, z_b)) < 1e-12


def test_eq_7_8_from_chosen_parameters_place_the_axes_as_described():
    """Forward direction: choose Phi and the cylinders, build P_b = P_r Q, check the geometry with Cylinder."""
    _, _, _, Pr, _, _, _ = constructed_tee(90.0)
    red, blue = np.array([0.05, -0.08, 0.03, 0.04]), np.array([-0.06, 0.1, -0.02, 0.05])
    params = np.array([0.7, -0.4, -1.1, -0.25, np.radians(70.0)])
    tee = TeeModel(params, red, blue, RADIUS)
    R_b, t_b = as_rt(tee.blue_pose(Pr))
    Cr = Cylinder.from_local(red, *Pr, RADIUS)
    Cb = Cylinder.from_local(blue, R_b, t_b, RADIUS)
    I = tee.intersection(Pr)
    assert abs(Cr.distance(I) + RADIUS) < 1e-12 and abs(Cb.distance(I) + RADIUS) < 1e-12  # on both axes
    assert np.degrees(np.arccos(Cr.direction @ Cb.direction)) == pytest.approx(70.0, abs=1e-9)
    assert (foot(Cr, Pr[1]) - I) @ Cr.direction == pytest.approx(params[1], abs=1e-12)
    assert (I - foot(Cb, t_b)) @ Cb.direction == pytest.approx(params[3], abs=1e-12)
    # The world blue cylinder depends on Phi and the red side only.
    other = TeeModel(params, red, blue + 0.05, RADIUS).blue_cylinder(Pr)
    assert np.abs(other.direction - Cb.direction).max() < 1e-12
    assert np.linalg.norm(np.cross(other.origin - Cb.origin, Cb.direction)) < 1e-12
    # Round trip through the initialiser.
    back = TeeModel.from_poses(Pr, (R_b, t_b), red, blue, RADIUS)
    assert np.abs(back.params - params).max() < 1e-10


def test_canonical_form_is_the_same_tee():
    _, _, _, Pr, _, _, _ = constructed_tee(90.0)
    tee = TeeModel([0.3, -0.4, 2.9, -0.2, -np.radians(50)], [0.01, 0.02, 0.0, 0.01], [0.0, -0.03, 0.02, 0.0], RADIUS)
    can = tee.canonical()
    assert 0 <= can.params[4] < np.pi and np.degrees(can.params[4]) == pytest.approx(50.0)
    assert np.abs(can.Q() - tee.Q()).max() < 1e-12


def numeric_pose_jacobian(f, x, eps=1e-6):
    """Central differences of the right perturbation delta = (R^T (t' - t), log(R^T R')) of a pose function."""
    R0, t0 = as_rt(f(x))
    J = np.zeros((6, len(x)))
    for i in range(len(x)):
        cols = []
        for s in (1, -1):
            xi = x.copy()
            xi[i] += s * eps
            R, t = as_rt(f(xi))
            cols.append(np.r_[R0.T @ (t - t0), log_so3(R0.T @ R)])
        J[:, i] = (cols[0] - cols[1]) / (2 * eps)
    return J


def test_q_jacobian_matches_numerical():
    tee = TeeModel([0.7, -0.4, -1.1, -0.25, np.radians(70.0)], [0.05, -0.08, 0.03, 0.04],
                   [-0.06, 0.1, -0.02, 0.05], RADIUS)
    J_phi, J_red, J_blue = tee.q_jacobian()

    def Q_of(x):
        return TeeModel(x[:5], x[5:9], x[9:], RADIUS).Q()

    num = numeric_pose_jacobian(Q_of, tee.vector)
    assert np.abs(num[:, :5] - J_phi).max() < 1e-8
    assert np.abs(num[:, 5:9] - J_red).max() < 1e-8
    assert np.abs(num[:, 9:] - J_blue).max() < 1e-8
    assert np.abs(J_phi).max() > 0.1  # not trivially zero


def test_attached_pose_moves_by_the_adjoint():
    rng = np.random.default_rng(3)
    T = to_matrix(exp_so3(rng.normal(size=3)), rng.normal(size=3))
    S = to_matrix(exp_so3(rng.normal(size=3)), rng.normal(size=3))
    xi = rng.normal(size=6) * 1e-6
    moved = T @ to_matrix(exp_so3(xi[3:]), xi[:3]) @ S
    R0, t0 = as_rt(T @ S)
    R1, t1 = as_rt(moved)
    delta = np.r_[R0.T @ (t1 - t0), log_so3(R0.T @ R1)]
    assert np.abs(delta - adjoint_of_inverse(S) @ xi).max() < 1e-10  # second order in |xi| ~ 1e-6


def test_distance_jacobians_match_numerical():
    I, z_r, z_b, Pr, Pb, Cr, Cb = constructed_tee(60.0)
    exact = TeeModel.initial(Cr, Cb, Pr, Pb)
    tee = exact.with_params(exact.params + [0.02, 0.01, -0.03, 0.02, 0.01])
    rng = np.random.default_rng(0)
    X = I + rng.normal(0, 0.3, (50, 3))
    d_r, d_b, Jr_X, Jb_X, Jb_phi = tee.distances(X, Pr)
    assert np.abs(d_r - Cr.distance(X)).max() < 1e-12
    assert np.abs(d_b - tee.blue_cylinder(Pr).distance(X)).max() < 1e-12
    eps = 1e-6
    for i in range(3):
        e = np.zeros(3)
        e[i] = eps
        p, m = tee.distances(X + e, Pr, jacobians=False), tee.distances(X - e, Pr, jacobians=False)
        assert np.abs((p[0] - m[0]) / (2 * eps) - Jr_X[:, i]).max() < 1e-7
        assert np.abs((p[1] - m[1]) / (2 * eps) - Jb_X[:, i]).max() < 1e-7
    for i in range(5):
        e = np.zeros(5)
        e[i] = eps
        p = tee.with_params(tee.params + e).distances(X, Pr, jacobians=False)[1]
        m = tee.with_params(tee.params - e).distances(X, Pr, jacobians=False)[1]
        assert np.abs((p - m) / (2 * eps) - Jb_phi[:, i]).max() < 1e-7
    assert np.abs(Jb_phi).max() > 0.05


@pytest.mark.parametrize("angle", [90.0, 60.0])
def test_initialiser_recovers_phi_from_noisy_cylinders(angle):
    """Axes off by ~0.5 deg and ~3 mm (so they miss each other): Phi within 1 deg and 1 cm, I within 1 cm."""
    I, z_r, z_b, Pr, Pb, Cr, Cb = constructed_tee(angle)
    truth = TeeModel.initial(Cr, Cb, Pr, Pb)
    rng = np.random.default_rng(7)
    errs = []
    for _ in range(5):
        noisy = [Cylinder(c.origin + rng.normal(0, 0.003, 3), c.direction + rng.normal(0, 0.006, 3), RADIUS)
                 for c in (Cr, Cb)]
        tee = TeeModel.initial(*noisy, Pr, Pb)
        d = tee.params - truth.params
        assert np.degrees(np.abs(d[[0, 2, 4]])).max() < 1.5
        assert np.abs(d[[1, 3]]).max() < 0.012
        errs.append(np.linalg.norm(tee.intersection(Pr) - I))
        assert 0 <= tee.params[4] < np.pi
    assert max(errs) < 0.012 and min(errs) > 0  # noisy, so never exact


def test_bad_radius_and_parameters_are_rejected():
    with pytest.raises(PipemapError, match="radius"):
        TeeModel(np.zeros(5), np.zeros(4), np.zeros(4), 0.0)
    with pytest.raises(ValueError, match="params"):
        TeeModel(np.zeros(4), np.zeros(4), np.zeros(4), 0.2)
