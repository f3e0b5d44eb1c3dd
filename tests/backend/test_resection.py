"""A keyframe's pose refined against the scene points it sees (backend/resection.py)."""

from __future__ import annotations

import numpy as np

from pipemap.backend.resection import ResectionProblem, resect
from pipemap.geometry.rotations import exp_so3, log_so3

from derivatives import numerical


def _scene(seed=0, n=120):
    rng = np.random.default_rng(seed)
    # the wall of a 150 mm pipe, 0.1-0.6 m ahead of a camera looking along it
    phi, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.1, 0.6, n)
    X = np.stack([0.15 * np.cos(phi), 0.15 * np.sin(phi) + 0.04, z], axis=1)
    R = exp_so3(np.radians([1.0, -2.0, 0.5]))
    c = np.array([0.003, -0.002, 0.01])
    b = (X - c) @ R
    return X, R, c, b / np.linalg.norm(b, axis=1, keepdims=True)


def test_jacobian_matches_numerical():
    X, R, c, b = _scene()
    p = ResectionProblem(exp_so3(np.radians([0.3, 0.1, -0.2])) @ R, c + 0.002, X, b)
    _, J = p.residuals(jacobian=True)
    assert np.allclose(J, numerical(lambda d: p.residuals(d), np.zeros(6)), atol=1e-7)


def test_recovers_the_pose_despite_noise_and_outliers():
    X, R, c, b = _scene(seed=1)
    rng = np.random.default_rng(2)
    noisy = b + np.radians(0.02) * rng.standard_normal(b.shape)  # 0.02 deg: a tenth of a pixel or so
    noisy[:10] = rng.standard_normal((10, 3))  # mismatches
    noisy /= np.linalg.norm(noisy, axis=1, keepdims=True)
    start_R, start_c = exp_so3(np.radians([0.5, -0.4, 0.3])) @ R, c + np.array([0.004, -0.003, 0.006])
    res = resect(start_R, start_c, X, noisy, np.radians(0.05))
    assert np.degrees(np.linalg.norm(log_so3(res.R.T @ R))) < 0.01
    assert np.linalg.norm(res.c - c) < 2e-4  # a fifth of a millimetre at 0.1-0.6 m
    assert not res.inliers[:10].any() and res.inliers[10:].mean() > 0.95
