"""Five-point RANSAC on bearings: exact minimal solutions, robustness, bearings past 90 deg."""

import numpy as np
import pytest

from pipemap.frontend.relpose import (
    continued_motion,
    decompose_essential,
    essential_from_pose,
    estimate_relative_pose,
    five_point,
    refine_pose,
    rotation_fits_motion,
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


def _pipe_views(R_cw0, motion, turn, half_fov_deg, n=400, seed=0, radius=0.15):
    """Bearings of wall points of a pipe along z (radius `radius`) seen from a camera turned by R_cw0 (camera
    to world) at the origin and from one moved by `motion` (world) and turned further by `turn` (camera frame):
    (R, bearings_i, bearings_j) with X_j = R X_i + t, only points within `half_fov_deg` of both optical axes."""
    rng = np.random.default_rng(seed)
    phi, z = rng.uniform(0, 2 * np.pi, 20 * n), rng.uniform(-3.0, 3.0, 20 * n)
    X = np.c_[radius * np.cos(phi), radius * np.sin(phi), z]
    R_cw1 = R_cw0 @ turn.T
    Xi = (X @ R_cw0)  # world -> camera 0: R_cw0^T X
    Xj = (X - motion) @ R_cw1
    bi = Xi / np.linalg.norm(Xi, axis=1, keepdims=True)
    bj = Xj / np.linalg.norm(Xj, axis=1, keepdims=True)
    inside = (bi[:, 2] > np.cos(np.radians(half_fov_deg))) & (bj[:, 2] > np.cos(np.radians(half_fov_deg)))
    bi, bj = bi[inside][:n], bj[inside][:n]
    return R_cw1.T @ R_cw0, bi, bj


FORWARD = np.eye(3)  # optical axis along the pipe
SIDEWAYS = exp_so3(np.array([0.0, np.pi / 2, 0.0]))  # optical axis square to the pipe, at its wall


@pytest.mark.parametrize("R_cw0, motion, turn, half_fov", [
    (FORWARD, [0, 0, 0.05], np.eye(3), 50.0),  # a CCTV camera driving on
    (FORWARD, [0, 0, 0.05], exp_so3(np.radians([0.0, 5.0, 0.0])), 50.0),  # in a bend
    (FORWARD, [0, 0, 0.02], exp_so3(np.radians([0.0, 0.0, 3.0])), 12.5),  # a narrow lens rolling
    (SIDEWAYS, [0, 0, 0.03], np.eye(3), 50.0),  # looking at the wall while driving past it: flow as if turned
    (FORWARD, [0, 0, 0.05], np.eye(3), 95.0),  # a fisheye
])
def test_a_true_pose_fits_the_motion_of_its_bearings(R_cw0, motion, turn, half_fov):
    R, bi, bj = _pipe_views(R_cw0, np.asarray(motion, float), turn, half_fov)
    assert len(bi) > 50
    assert rotation_fits_motion(R, bi, bj, factor=1.5, slack_deg=1.0)


def test_a_pose_turned_past_what_its_bearings_moved_is_refused():
    """The far end of the pipe only (bearings within 8 deg of the axis, as a CCTV camera's inliers were on
    compressed 320x240 footage): a pose turned 20 deg, whose epipolar lines such a cone cannot tell apart."""
    R, bi, bj = _pipe_views(FORWARD, np.array([0, 0, 0.05]), np.eye(3), 8.0)
    assert len(bi) > 20
    assert rotation_fits_motion(R, bi, bj, factor=1.5, slack_deg=1.0)
    for axis in np.eye(3):
        wrong = exp_so3(np.radians(20.0) * axis) @ R
        assert not rotation_fits_motion(wrong, bi, bj, factor=1.5, slack_deg=1.0)
    # a 3 deg error on an 8 deg cone that moved by about a degree is still within the slack's reach
    moved = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", bi, bj), -1, 1)))
    bound = 1.5 * np.percentile(moved, 90) + 1.0
    assert rotation_fits_motion(exp_so3(np.radians(0.9 * bound) * np.eye(3)[0]) @ R, bi, bj, 1.5, 1.0)
    assert not rotation_fits_motion(exp_so3(np.radians(1.1 * bound) * np.eye(3)[0]) @ R, bi, bj, 1.5, 1.0)


def test_the_previous_motion_continues_where_the_pairs_cannot_tell_it_from_ransacs_pose():
    """The far end's cone of bearings only: RANSAC's pose turned 7 deg with its translation off the axis fits the
    pairs as a wide field's would not; the straight drive before, refined on the same pairs, keeps them all."""
    R, bi, bj = _pipe_views(FORWARD, np.array([0, 0, 0.05]), np.eye(3), 8.0)
    t = np.array([0.0, 0.0, -1.0])  # X_j = R X_i + t: the camera drove along +z
    wrong_R = exp_so3(np.radians([7.0, 0.0, 0.0])) @ R
    wrong_t = np.array([-0.78, 0.46, -0.43]) / np.linalg.norm([-0.78, 0.46, -0.43])
    some = np.zeros(len(bi), bool)
    some[: int(0.9 * len(bi))] = True  # RANSAC's pose counted a few more pairs than the truth keeps below
    prior_R = exp_so3(np.radians([0.3, -0.2, 0.1]))  # the keyframe before drove on, turning a little
    found = continued_motion(wrong_R, wrong_t, some, prior_R, t, bi, bj, np.radians(0.05), 0.8, 1.0)
    assert found is not None
    R_found, t_found, inliers = found
    assert rotation_angle(R_found @ R.T) < np.radians(0.2)
    assert angle_deg(t_found, t) < 3.0
    assert inliers.mean() > 0.95


def test_a_wide_view_settles_the_pose_itself():
    """Bearings all round a fisheye: the previous motion (a turn of 5 deg) refined on the pairs comes back to
    RANSAC's straight drive, which stays."""
    R, bi, bj = _pipe_views(FORWARD, np.array([0, 0, 0.05]), np.eye(3), 95.0)
    t = np.array([0.0, 0.0, -1.0])
    everything = np.ones(len(bi), bool)
    prior_R = exp_so3(np.radians([0.0, 5.0, 0.0]))
    assert continued_motion(R, t, everything, prior_R, t, bi, bj, np.radians(0.05), 0.8, 1.0) is None
