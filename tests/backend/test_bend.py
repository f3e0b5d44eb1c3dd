"""The bent pipe axis: interpolation, the wall distance and its Jacobians, the prior and the fit."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.geometry.bend import AxisKnots, fit_bend
from pipemap.geometry.cylinder import distance_jacobians, local_distance
from pipemap.geometry.rotations import exp_so3
from pipemap.geometry.se3 import retract

from derivatives import numerical

RADIUS = 0.2


def test_knots_interpolate_linearly_and_hold_the_end_values_beyond():
    knots = AxisKnots.spanning(-0.3, 0.7, 0.25)
    assert len(knots) == 5 and np.isclose(knots.spacing, 0.25)
    o = np.array([[0.0, 1.0], [2.0, 1.0], [2.0, 3.0], [0.0, 0.0], [1.0, 1.0]])
    z = np.array([-1.0, -0.3, -0.175, 0.2, 0.6, 2.0])
    assert np.allclose(knots.at(o, z), [[0, 1], [0, 1], [1, 1], [2, 3], [0.6, 0.6], [1, 1]])
    assert np.allclose(knots.slope(o, z)[[0, -1]], 0.0)
    assert np.allclose(knots.slope(o, [-0.2]), [[8.0, 0.0]])


def test_bent_distance_jacobians_match_numerical_ones():
    rng = np.random.default_rng(3)
    R, t = exp_so3(rng.normal(0, 0.3, 3)), rng.normal(0, 1.0, 3)
    knots = AxisKnots.spanning(0.1, 1.6, 0.25)
    p = np.concatenate([[-0.05, 0.2, 0.01, 0.03], rng.normal(0, 0.004, 2 * len(knots))])
    # Points along the pipe ahead of the reference camera, off the knots (the slope jumps there).
    z = rng.uniform(-0.2, 1.9, 40)
    z += np.where(np.min(np.abs(z[:, None] - knots.z), axis=1) < 1e-3, 2e-3, 0.0)
    ang = rng.uniform(0, 2 * np.pi, 40)
    Xm = np.column_stack([0.19 * np.cos(ang), 0.19 * np.sin(ang), z])
    X = Xm @ R.T + t
    d, J_X, J_p, J_ref = distance_jacobians(X, p, R, t, RADIUS, knots=knots)
    tol = 1e-7
    assert np.abs(numerical(lambda q: distance_jacobians(X, q, R, t, RADIUS, knots=knots)[0], p) - J_p).max() < tol
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1e-6
        num = (distance_jacobians(X + e, p, R, t, RADIUS, knots=knots)[0]
               - distance_jacobians(X - e, p, R, t, RADIUS, knots=knots)[0]) / 2e-6
        assert np.abs(num - J_X[:, k]).max() < tol
    num = numerical(lambda dl: distance_jacobians(X, p, *retract(R, t, dl), RADIUS, knots=knots)[0], np.zeros(6))
    assert np.abs(num - J_ref).max() < tol
    # Zero offsets: the straight cylinder's distance.
    p0 = p.copy()
    p0[4:] = 0
    assert np.allclose(local_distance(Xm, p0, RADIUS, jacobians=False, knots=knots),
                       local_distance(Xm, p0[:4], RADIUS, jacobians=False), atol=1e-15)


def test_the_prior_ignores_a_straight_line_only_through_its_weak_offset_term():
    knots = AxisKnots.spanning(0.0, 1.0, 0.25)
    P = knots.prior(2, np.radians(0.5))
    line = np.column_stack([0.001 + 0.002 * knots.z, -0.003 * knots.z]).ravel()
    kink = np.zeros((len(knots), 2))
    kink[2, 0] = 0.001  # 1 mm out at the middle knot: a kink of 8 mrad
    n = len(knots) * 2
    assert np.abs((P @ line)[n:]).max() < 1e-12
    assert np.isclose(np.abs((P @ kink.ravel())[n:]).max(), 0.002 / 0.25 / np.radians(0.5))


@pytest.mark.parametrize("joint", [0.75, 0.9])
def test_fit_follows_a_kinked_joint_to_a_fraction_of_a_millimetre(joint):
    """A pipe of two pieces that meet 2 mm low at a joint: the fitted axis follows the V."""
    rng = np.random.default_rng(7)
    h = rng.uniform(0.0, 1.6, 4000)
    sag = -0.002 * np.where(h < joint, h / joint, (1.6 - h) / (1.6 - joint))  # the axis drops to the joint
    ang = rng.uniform(0, 2 * np.pi, len(h))
    across = np.column_stack([RADIUS * np.cos(ang) + sag, RADIUS * np.sin(ang)]) + rng.normal(0, 1e-4, (len(h), 2))
    knots, o = fit_bend(h, across, RADIUS, 0.25, np.radians(0.5), huber=0.005, sigma_m=0.002)
    truth = -0.002 * np.where(knots.z < joint, knots.z / joint, (1.6 - knots.z) / (1.6 - joint))
    # The straight part is the gauge's: compare after removing the best line from both.
    A = np.column_stack([np.ones(len(knots)), knots.z])
    def detrend(v):
        return v - A @ np.linalg.lstsq(A, v, rcond=None)[0]
    err = detrend(o[:, 0]) - detrend(truth)
    # A knot falls on the joint at 0.75 m but not at 0.9 m: linear pieces round the V off there.
    assert np.abs(err).max() < (0.1e-3 if joint == 0.75 else 0.35e-3)
    assert np.abs(o[:, 1] - np.polyval(np.polyfit(knots.z, o[:, 1], 1), knots.z)).max() < 0.05e-3


def test_knot_normal_equations_equal_those_of_the_dense_jacobian():
    """The fit sums J^T W J point by point over each point's two knots; the same as forming J (M, 2K)."""
    from pipemap.geometry.bend import _knot_normal_equations, bent_distance
    rng = np.random.default_rng(3)
    h = rng.uniform(-0.2, 2.1, 500)  # some beyond the end knots, where the offset is the end knot's
    ang = rng.uniform(0, 2 * np.pi, len(h))
    across = np.column_stack([np.cos(ang), np.sin(ang)]) * (RADIUS + rng.normal(0, 0.003, len(h)))[:, None]
    knots = AxisKnots.spanning(0.0, 1.9, 0.25)
    o = rng.normal(0, 0.001, (len(knots), 2))
    d, n, i, f = bent_distance(across, h, knots, o, RADIUS)
    w = rng.uniform(0.5, 2.0, len(h))
    _, J_p = local_distance(np.column_stack([across, h]), np.concatenate([np.zeros(4), o.ravel()]), RADIUS,
                            knots=knots)[::2]
    J = J_p[:, 4:]
    H, g = _knot_normal_equations(i, f, n[:, :2], w, d, len(knots))
    assert np.allclose(H, J.T @ (w[:, None] * J), rtol=1e-12, atol=1e-12)
    assert np.allclose(g, J.T @ (w * d), rtol=1e-12, atol=1e-12)
