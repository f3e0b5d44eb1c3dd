"""Five-point RANSAC on bearings: exact minimal solutions, robustness, bearings past 90 deg."""

import numpy as np
import pytest

from pipemap.frontend.relpose import (
    decompose_essential,
    essential_from_pose,
    estimate_relative_pose,
    five_point,
    refine_pose,
    sampson_angle,
    signed_sampson,
)
from pipemap.geometry.rotations import exp_so3, rotation_angle


def two_views(n=300, seed=0, behind_fraction=0.3):
    """Bearings of random points all around both cameras, many of them past 90 deg."""
    rng = np.random.default_rng(seed)
    R = exp_so3(rng.normal(scale=0.1, size=3))
    t = rng.normal(size=3)
    t /= np.linalg.norm(t)
    X = rng.normal(size=(n, 3)) * 3.0
    X[: int(behind_fraction * n), 2] = -np.abs(X[: int(behind_fraction * n), 2])  # colatitude > 90 deg
    Xj = X @ R.T + t
    bi = X / np.linalg.norm(X, axis=1, keepdims=True)
    bj = Xj / np.linalg.norm(Xj, axis=1, keepdims=True)
    return R, t, bi, bj, rng


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(a @ b, -1, 1)))


def test_five_point_recovers_the_true_essential_matrix_in_every_sample():
    R, t, bi, bj, rng = two_views()
    E_true = essential_from_pose(R, t)
    E_true /= np.linalg.norm(E_true)
    samples = np.argsort(rng.random((50, len(bi))), axis=1)[:, :5]
    E, sample = five_point(bi[samples], bj[samples])
    dist = np.minimum(np.linalg.norm(E - E_true, axis=(1, 2)), np.linalg.norm(E + E_true, axis=(1, 2)))
    assert set(sample[dist < 1e-8]) == set(range(50))
    # Every returned solution satisfies its own five constraints.
    residual = np.abs(np.einsum("mni,mij,mnj->mn", bj[samples][sample], E, bi[samples][sample]))
    assert residual.max() < 1e-8


def test_sampson_angle_is_zero_for_true_pairs_and_measures_angular_offsets():
    R, t, bi, bj, rng = two_views()
    E = essential_from_pose(R, t)
    assert sampson_angle(E, bi, bj).max() < 1e-10
    # Rotate eta_j by 0.01 rad about an axis in the epipolar plane: it leaves the plane by 0.01 rad.
    normal = bi @ E.T
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    axis = np.cross(normal, bj)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    moved = np.stack([exp_so3(0.01 * a) @ b for a, b in zip(axis, bj)])
    err = sampson_angle(E, bi, moved)
    # The least correction may move both bearings, so it is at most the 0.01 rad that eta_j moved;
    # and to first order it is linear in the offset.
    assert np.all(err < 0.0101) and np.median(err) > 0.005
    moved2 = np.stack([exp_so3(0.002 * a) @ b for a, b in zip(axis, bj)])
    assert np.allclose(sampson_angle(E, bi, moved2), 0.2 * err, rtol=0.02)


def test_decomposition_chooses_the_pose_with_points_in_front_also_past_90_degrees():
    R, t, bi, bj, _ = two_views(behind_fraction=0.6)
    R_est, t_est, count = decompose_essential(essential_from_pose(R, t), bi, bj)
    assert count == len(bi)
    assert np.degrees(rotation_angle(R_est @ R.T)) < 1e-6
    assert angle_deg(t_est, t) < 1e-6


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ransac_with_noise_and_outliers(seed):
    R, t, bi, bj, rng = two_views(n=400, seed=seed)
    noise = np.radians(0.05)
    bj = bj + rng.normal(scale=noise / np.sqrt(2), size=bj.shape)
    bj /= np.linalg.norm(bj, axis=1, keepdims=True)
    outliers = rng.random(len(bi)) < 0.35
    bj[outliers] = rng.normal(size=(outliers.sum(), 3))
    bj /= np.linalg.norm(bj, axis=1, keepdims=True)
    pose = estimate_relative_pose(bi, bj, np.radians(0.2), rng=np.random.default_rng(seed))
    assert pose is not None
    assert np.degrees(rotation_angle(pose.R @ R.T)) < 0.05
    assert angle_deg(pose.t, t) < 0.3
    assert np.mean(pose.inliers[~outliers]) > 0.9
    assert np.mean(pose.inliers[outliers]) < 0.02


def test_ransac_is_deterministic_for_a_seed_and_refuses_too_few_pairs():
    R, t, bi, bj, _ = two_views(n=100)
    a = estimate_relative_pose(bi, bj, 1e-3, rng=np.random.default_rng(5))
    b = estimate_relative_pose(bi, bj, 1e-3, rng=np.random.default_rng(5))
    assert np.array_equal(a.R, b.R) and np.array_equal(a.inliers, b.inliers)
    assert estimate_relative_pose(bi[:4], bj[:4], 1e-3) is None
    # Pure noise has no consensus.
    rng = np.random.default_rng(0)
    noise = rng.normal(size=(60, 3))
    noise /= np.linalg.norm(noise, axis=1, keepdims=True)
    assert estimate_relative_pose(bi[:60], noise, 1e-4, min_inliers=15) is None


def test_signed_sampson_matches_the_sampson_angle_and_its_derivative_the_numerical_one():
    R, t, bi, bj, rng = two_views(n=50, seed=3)
    bj = bj + rng.normal(scale=0.01, size=bj.shape)
    bj /= np.linalg.norm(bj, axis=1, keepdims=True)
    E = essential_from_pose(R, t)
    r, d = signed_sampson(E, bi, bj)
    assert np.allclose(np.abs(r), sampson_angle(E, bi, bj), rtol=1e-12, atol=1e-15)
    h = 1e-7
    numeric = np.stack([(signed_sampson(E + h * np.eye(9)[k].reshape(3, 3), bi, bj)[0]
                         - signed_sampson(E - h * np.eye(9)[k].reshape(3, 3), bi, bj)[0]) / (2 * h)
                        for k in range(9)], axis=1)
    assert np.allclose(d, numeric, rtol=1e-6, atol=1e-8)


def test_refine_pose_recovers_the_pose_from_a_perturbed_start():
    R, t, bi, bj, rng = two_views(n=300, seed=4)
    noise = np.radians(0.02)
    bj = bj + rng.normal(scale=noise / np.sqrt(2), size=bj.shape)
    bj /= np.linalg.norm(bj, axis=1, keepdims=True)
    start_R = exp_so3(np.radians([0.3, -0.2, 0.25])) @ R
    start_t = t + np.array([0.02, -0.01, 0.015])
    R_est, t_est = refine_pose(start_R, start_t / np.linalg.norm(start_t), bi, bj, noise)
    # 300 pairs at 0.02 deg: the pose to a few thousandths of a degree, the direction to under a hundredth
    assert np.degrees(rotation_angle(R_est @ R.T)) < 0.005
    assert angle_deg(t_est, t) < 0.015
