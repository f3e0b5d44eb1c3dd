"""Cylinders: the paper's 4-DOF parameterisation, distances and their Jacobians, ray intersection, robust fit."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.camera import PolynomialCamera
from pipemap.errors import PipemapError
from pipemap.geometry.cylinder import (Cylinder, distance_jacobians, fit_cylinder, local_distance, local_frame, rot_x,
                                       rot_y)
from pipemap.geometry.rotations import exp_so3, look_rotation
from pipemap.geometry.se3 import retract

from derivatives import numerical

RADIUS = 0.2


def reference(seed=0):
    rng = np.random.default_rng(seed)
    return exp_so3(rng.normal(0, 0.4, 3)), rng.normal(0, 1.0, 3)


def test_parameterisation_follows_eq_4_5():
    R, t = reference()
    p = np.array([0.1, -0.25, 0.03, -0.02])
    Rt, tt = local_frame(p)
    assert np.allclose(Rt, rot_x(0.1) @ rot_y(-0.25)) and np.allclose(tt, [0.03, -0.02, 0])
    cyl = Cylinder.from_local(p, R, t, RADIUS)
    X = np.random.default_rng(1).normal(0, 0.5, (20, 3))
    Xt = (X - t) @ R @ Rt.T + tt  # eq. 5 with R_m = R^T, t_m = -R^T t
    assert np.allclose(np.hypot(Xt[:, 0], Xt[:, 1]) - RADIUS, cyl.distance(X), atol=1e-12)
    assert np.allclose(cyl.local_params(R, t), p, atol=1e-12)
    # The cylinder origin is the foot of the reference camera centre on the axis.
    assert abs((t - cyl.origin) @ cyl.direction) < 1e-12
    # gamma = beta = 0: the axis is the reference camera's optical axis.
    assert np.allclose(Cylinder.from_local([0, 0, 0, 0], R, t, RADIUS).direction, R[:, 2], atol=1e-12)


def test_local_params_orient_the_axis_forward_and_survive_any_origin():
    R, t = reference(2)
    cyl = Cylinder(t + 0.3 * R[:, 0], -(R[:, 2] + 0.2 * R[:, 1]), RADIUS)  # axis pointing backwards
    p = cyl.local_params(R, t)
    back = Cylinder.from_local(p, R, t, RADIUS)
    assert abs(abs(back.direction @ cyl.direction) - 1) < 1e-12
    assert back.direction @ R[:, 2] > 0
    X = np.random.default_rng(3).normal(0, 0.5, (50, 3)) + t
    assert np.allclose(back.distance(X), cyl.distance(X), atol=1e-12)


def test_distance_jacobians_match_numerical_ones():
    R, t = reference(4)
    p = np.array([-0.08, 0.3, 0.01, 0.04])
    X = np.random.default_rng(5).normal(0, 0.4, (30, 3)) + t
    d, J_X, J_p, J_ref = distance_jacobians(X, p, R, t, RADIUS)
    tol = 1e-7  # central differences with eps = 1e-6 on O(1) quantities
    assert np.abs(numerical(lambda q: distance_jacobians(X, q, R, t, RADIUS)[0], p) - J_p).max() < tol
    for k in range(3):  # each point's gradient, one coordinate at a time
        e = np.zeros(3)
        e[k] = 1e-6
        num = (distance_jacobians(X + e, p, R, t, RADIUS)[0] - distance_jacobians(X - e, p, R, t, RADIUS)[0]) / 2e-6
        assert np.abs(num - J_X[:, k]).max() < tol
    num = numerical(lambda dl: distance_jacobians(X, p, *retract(R, t, dl), RADIUS)[0], np.zeros(6))
    assert np.abs(num - J_ref).max() < tol
    cyl = Cylinder.from_local(p, R, t, RADIUS)
    d2, J2 = cyl.distance_jacobian(X)
    assert np.allclose(d2, d, atol=1e-12) and np.allclose(J2, J_X, atol=1e-12)
    Xm = (X - t) @ R
    assert np.allclose(local_distance(Xm, p, RADIUS, jacobians=False), d, atol=1e-12)


def test_rays_from_inside_exit_on_the_wall_also_beyond_90_degrees():
    R, t = reference(6)
    cyl = Cylinder(t + 0.05 * R[:, 1] - 0.03 * R[:, 0], R[:, 2] + 0.1 * R[:, 0], RADIUS)  # camera off-axis, tilted
    # Bearings over the whole sphere, in the camera frame; colatitudes up to 180 deg.
    theta = np.linspace(0, np.pi, 91)[1:-1]
    phi = np.linspace(-np.pi, np.pi, 73)
    th, ph = np.meshgrid(theta, phi)
    b = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    P, s, valid = cyl.intersect_bearings(R, t, b)
    assert valid.all() and np.all(s > 0)
    assert np.abs(cyl.distance(P)).max() < 1e-9
    assert np.abs(np.cross(P - t, b @ R.T)).max() < 1e-9  # on the ray, not behind the camera
    # ...and the bearings of a 190 deg fisheye, from its own unprojection at the image border.
    cam = PolynomialCamera(640, 480, dict(k1=150.0, k2=-3.0, k3=0.5, k4=0.0, u0=320.3, v0=239.6), 95)
    ang = np.linspace(0, 2 * np.pi, 50)
    uv = np.stack([320.3 + 238 * np.cos(ang), 239.6 + 238 * np.sin(ang)], -1)
    bear, ok = cam.unproject(uv)
    assert ok.all() and np.degrees(cam.colatitude(bear)).min() > 90
    P, s, valid = cyl.intersect_bearings(R, t, bear)
    assert valid.all() and np.abs(cyl.distance(P)).max() < 1e-9


def test_rays_parallel_to_the_axis_or_missing_from_outside_are_invalid():
    cyl = Cylinder([0, 0, 0], [0, 0, 1], RADIUS)
    P, s, valid = cyl.intersect(np.array([[0.05, 0, 0], [1.0, 0, 0], [1.0, 0, 0]]),
                                np.array([[0, 0, 1.0], [0, 1.0, 0], [-1.0, 0, 0]]))
    assert list(valid) == [False, False, True]
    assert np.allclose(P[2], [RADIUS, 0, 0], atol=1e-12)  # from outside: the nearest entry


def wall_points(rng, cyl_true, n=2000, length=1.0, noise=0.001, outliers=0.1):
    z = rng.uniform(0, length, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    u = np.cross(cyl_true.direction, [0.3, 1, 0.2])
    u /= np.linalg.norm(u)
    v = np.cross(cyl_true.direction, u)
    r = RADIUS + rng.normal(0, noise, n)
    bad = rng.random(n) < outliers
    r[bad] = rng.uniform(0.02, RADIUS - 0.02, bad.sum())  # debris inside the pipe
    X = (cyl_true.origin + z[:, None] * cyl_true.direction
         + r[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v))
    return X, bad


def axis_errors(fit, true, X):
    """Angle between the axes (deg) and the largest distance between them over the points' extent (m)."""
    ang = np.degrees(np.arccos(min(1.0, abs(fit.direction @ true.direction))))
    s = true.axial(X)
    on_true = true.origin + np.outer([s.min(), s.max()], true.direction)
    off = on_true - fit.origin
    off -= np.outer(off @ fit.direction, fit.direction)
    return ang, np.linalg.norm(off, axis=1).max()


@pytest.mark.parametrize("init", ["pca", "path", "reference"])
def test_fit_recovers_a_known_cylinder_from_noisy_points(init):
    rng = np.random.default_rng(7)
    true = Cylinder([0.4, -1.0, 2.0], [0.6, 0.2, 0.77], RADIUS)
    X, bad = wall_points(rng, true)
    kw = {}
    if init == "path":
        kw["direction"] = true.direction + np.array([0.05, -0.04, 0.02])  # a rough camera-path direction
    if init == "reference":  # a camera inside, looking roughly along the pipe
        R = look_rotation(true.direction + np.array([0.1, 0.05, 0.0]), np.array([0.0, 0.0, 1.0]))  # tilted ~6 deg
        kw["reference"] = (R, true.origin + 0.05 * R[:, 0])
    fit = fit_cylinder(X, RADIUS, **kw)
    ang, off = axis_errors(fit.cylinder, true, X)
    assert ang < 0.1  # deg
    assert off < 0.001  # m
    assert fit.inliers[bad].mean() < 0.05 and fit.inliers[~bad].mean() > 0.97
    assert abs(fit.rms - 0.001) < 0.0003
    assert np.allclose(fit.cylinder.local_params(*fit.reference), fit.params, atol=1e-9)


def test_fit_covariance_matches_the_scatter_of_repeated_fits():
    """rms^2 (J^T J)^-1 against the spread of the parameters over 40 noise draws (1 mm, no outliers)."""
    reference = (np.eye(3), np.zeros(3))
    params, sds = [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        phi, z = rng.uniform(0, 2 * np.pi, 400), rng.uniform(0.0, 0.5, 400)
        X = np.column_stack([RADIUS * np.cos(phi), RADIUS * np.sin(phi), z]) + rng.normal(0, 0.001, (400, 3))
        fit = fit_cylinder(X, RADIUS, reference=reference, direction=[0, 0, 1.0])
        params.append(fit.params)
        sds.append(np.sqrt(np.diag(fit.covariance)))
    ratio = np.std(params, axis=0) / np.mean(sds, axis=0)
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio


def test_fit_reports_the_scale_error_through_the_free_radius():
    rng = np.random.default_rng(8)
    true = Cylinder([0, 0, 0], [1, 0, 0], RADIUS)
    X, _ = wall_points(rng, true, outliers=0.0)
    fit = fit_cylinder(0.9 * X, RADIUS)
    assert abs(fit.free_radius / RADIUS - 0.9) < 0.002


@pytest.mark.parametrize("radius", [0.0, -0.1, float("nan")])
def test_a_bad_radius_is_a_clear_error(radius):
    with pytest.raises(PipemapError, match="radius"):
        Cylinder([0, 0, 0], [0, 0, 1], radius)
    with pytest.raises(PipemapError, match="radius"):
        fit_cylinder(np.random.default_rng(0).normal(size=(20, 3)), radius)


def test_fit_rejects_too_few_points():
    with pytest.raises(ValueError, match="at least 5"):
        fit_cylinder(np.zeros((3, 3)), RADIUS)


def test_a_path_that_turned_back_keeps_its_chord_along_the_pipe():
    from pipemap.geometry.cylinder import foremost, path_chord

    along = np.r_[np.linspace(0.0, 2.0, 41), np.linspace(1.95, 0.0, 40)]
    path = np.c_[0.001 * np.sin(np.arange(81)), np.zeros(81), along]
    assert foremost(path) == 40
    assert np.allclose(path_chord(path), path[40] - path[0])
    assert foremost(path[:30]) == 29  # one way: the last centre
