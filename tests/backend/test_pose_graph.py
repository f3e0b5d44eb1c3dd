"""Pose-graph optimisation: a square loop of four straight pipes, driven around once and then
along the first side again, with drift injected into the odometry and loop-closure edges between
the two visits of the first side."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.backend.pose_graph import (PoseEdge, odometry_covariance, optimise_pose_graph, relative_poses,
                                        temporal_edges)
from pipemap.geometry.rotations import exp_so3, look_rotation, rotation_angle
from pipemap.geometry.se3 import as_rt, compose, invert, retract, to_matrix
from pipemap.sim.route import AxisPath

SIDE = 4.0
LOOP_COV = np.diag([0.002**2] * 3 + [np.radians(0.1) ** 2] * 3)


def square_route(spacing: float = 0.1):
    """True T_wc (N, 4, 4) along the square (tees at the corners, 0.2 m turns) and arc lengths."""
    corners = np.array([[0, 0, 0], [SIDE, 0, 0], [SIDE, SIDE, 0], [0, SIDE, 0]], float)
    path = AxisPath(np.array([[1.0, 0, 0], corners[1], corners[2], corners[3], corners[0], [3.0, 0, 0]]), 0.2)
    s = np.append(np.arange(0.0, path.length, spacing), path.length)
    pos, tan = path.evaluate(s)
    return to_matrix(look_rotation(tan, np.array([0.0, 0.0, 1.0])), pos), s, path


def integrate(first: np.ndarray, steps: np.ndarray) -> np.ndarray:
    R, t = [first[:3, :3]], [first[:3, 3]]
    for Rs, ts in zip(*as_rt(steps)):
        r, p = compose(R[-1], t[-1], Rs, ts)
        R.append(r)
        t.append(p)
    return to_matrix(np.array(R), np.array(t))


def drifted(T: np.ndarray, yaw_deg_per_m: float = 1.0, scale: float = 0.01, seed: int = 0) -> np.ndarray:
    """Odometry with a heading bias, a scale error and a little noise, integrated from the true first pose."""
    rng = np.random.default_rng(seed)
    R, t = as_rt(relative_poses(T))
    L = np.linalg.norm(t, axis=1)
    # Camera y points down, so a yaw to the left is about -y.
    phi = np.radians(yaw_deg_per_m) * L[:, None] * np.array([0.0, -1.0, 0.0])
    phi += rng.normal(scale=np.radians(0.02), size=phi.shape) * np.sqrt(L)[:, None]
    return integrate(T[0], to_matrix(R @ exp_so3(phi), t * (1.0 + scale)))


def true_edge(T, i, j, rng=None, cov=LOOP_COV, loop=True) -> PoseEdge:
    Ri, ti = invert(*as_rt(T[i]))
    R, t = compose(Ri, ti, *as_rt(T[j]))
    if rng is not None:
        R, t = retract(R, t, rng.multivariate_normal(np.zeros(6), cov))
    return PoseEdge.from_covariance(i, j, to_matrix(R, t), cov, loop=loop)


def revisit_pairs(T, s, path, every: int = 3):
    """Keyframes of the first side's first visit and their nearest keyframe on the second visit."""
    pos = T[:, :3, 3]
    first = np.nonzero(s < path.vertex_s[1] - 0.3)[0]
    last = np.nonzero(s > path.vertex_s[4] + 0.3)[0]
    pairs = [(i, last[np.argmin(np.linalg.norm(pos[last] - pos[i], axis=1))]) for i in first[::every]]
    return [(int(i), int(j)) for i, j in pairs if np.linalg.norm(pos[j] - pos[i]) < 0.06]


@pytest.fixture(scope="module")
def square():
    T, s, path = square_route()
    pairs = revisit_pairs(T, s, path)
    rng = np.random.default_rng(1)
    loops = [true_edge(T, i, j, rng) for i, j in pairs]
    return T, drifted(T), loops


def position_errors(P, T):
    return np.linalg.norm(P[:, :3, 3] - T[:, :3, 3], axis=1)


def test_square_loop_closes(square):
    T, D, loops = square
    assert len(loops) >= 5
    before = position_errors(D, T)
    assert before[-1] > 0.3  # the drift is real: tens of cm at the end
    out = optimise_pose_graph(D, temporal_edges(D) + loops)
    after = position_errors(out, T)
    assert after[-1] < before[-1] / 10
    assert after.max() < before.max() / 5
    # The loop edges hold: revisit poses sit where the first visit says, to a few mm.
    for e in loops:
        Ri, ti = invert(*as_rt(out[e.i]))
        R, t = compose(Ri, ti, *as_rt(out[e.j]))
        assert np.linalg.norm(t - e.T_ij[:3, 3]) < 0.01
        assert np.degrees(rotation_angle(R.T @ e.T_ij[:3, :3])) < 0.5


def test_first_pose_is_held_exactly(square):
    T, D, loops = square
    out = optimise_pose_graph(D, temporal_edges(D) + loops)
    np.testing.assert_allclose(out[0], D[0], atol=1e-12)
    held = optimise_pose_graph(D, temporal_edges(D) + loops, fixed=10)
    np.testing.assert_allclose(held[10], D[10], atol=1e-12)
    # Holding another pose only moves the whole solution rigidly.
    Rd, td = compose(*as_rt(held[10]), *invert(*as_rt(out[10])))
    moved = to_matrix(*compose(Rd, td, *as_rt(out)))
    np.testing.assert_allclose(moved[:, :3, 3], held[:, :3, 3], atol=1e-4)


def test_each_edge_is_weighted_by_its_covariance():
    """One turn's odometry is bad and says so; every other step is good. The closure must be taken up
    at that turn. With one covariance for every edge the correction is smeared along the loop."""
    T, s, path = square_route()
    steps = relative_poses(T)
    corner = int(np.searchsorted(s, path.vertex_s[2]))  # the second turn
    bad = steps.copy()
    R, t = retract(*as_rt(steps[corner]), np.array([0.03, 0.0, -0.05, 0.0, np.radians(3.0), 0.0]))
    bad[corner] = to_matrix(R, t)
    D = integrate(T[0], bad)
    edges = temporal_edges(D, translation_sigma_m=0.001, rotation_sigma_rad=np.radians(0.01))
    edges[corner] = PoseEdge.from_covariance(corner, corner + 1, bad[corner],
                                             np.diag([0.1**2] * 3 + [np.radians(5.0) ** 2] * 3))
    loops = [true_edge(T, i, j) for i, j in revisit_pairs(T, s, path)]
    weighted = position_errors(optimise_pose_graph(D, edges + loops), T)
    mean_cov = np.mean([np.linalg.inv(e.information) for e in edges], axis=0)
    uniform_edges = [PoseEdge.from_covariance(e.i, e.j, e.T_ij, mean_cov) for e in edges]
    uniform = position_errors(optimise_pose_graph(D, uniform_edges + loops), T)
    assert position_errors(D, T).max() > 0.2
    assert weighted.max() < 0.002
    assert uniform.max() > 0.03


def test_information_is_translation_then_rotation():
    """Two conflicting measurements of one step: A is sure of the translation, B of the rotation. The
    answer takes each part from the edge that is sure of it (swapped blocks would do the opposite)."""
    poses = np.stack([np.eye(4), np.eye(4)])
    Ra, ta = exp_so3(np.array([0.0, 0.0, 0.2])), np.array([1.0, 0.0, 0.0])
    Rb, tb = exp_so3(np.array([0.0, 0.0, -0.1])), np.array([1.2, 0.3, 0.0])
    sure_t = np.diag([1e-6] * 3 + [1.0] * 3)
    sure_r = np.diag([1.0] * 3 + [1e-6] * 3)
    edges = [PoseEdge.from_covariance(0, 1, to_matrix(Ra, ta), sure_t),
             PoseEdge.from_covariance(0, 1, to_matrix(Rb, tb), sure_r)]
    out = optimise_pose_graph(poses, edges)
    np.testing.assert_allclose(out[1, :3, 3], ta, atol=1e-3)
    assert np.degrees(rotation_angle(out[1, :3, :3].T @ Rb)) < 0.1


def test_robust_kernel_resists_a_wrong_closure(square):
    T, D, loops = square
    good = position_errors(optimise_pose_graph(D, temporal_edges(D) + loops), T)
    e = loops[len(loops) // 2]
    wrong_T = e.T_ij.copy()
    wrong_T[:3, 3] += [0.0, 0.0, 0.5]  # paired with the wrong place, half a metre along the pipe
    edges = temporal_edges(D) + loops + [PoseEdge(e.i, e.j, wrong_T, e.information, loop=True)]
    plain = position_errors(optimise_pose_graph(D, edges, kernel=None), T)
    assert plain.max() > good.max() + 0.02
    for kernel in ("huber", "cauchy"):
        robust = position_errors(optimise_pose_graph(D, edges, kernel=kernel), T)
        assert robust.max() < good.max() + 0.01, kernel


def test_odometry_variance_grows_with_distance():
    cov = odometry_covariance(np.array([0.5, 0.2, 0.3, 1.0]), 0.01, np.radians(0.5))
    # Cutting one metre into pieces gives the same total variance.
    np.testing.assert_allclose(cov[:3].sum(axis=0), cov[3], rtol=1e-12)
    np.testing.assert_allclose(np.diag(cov[3]), [1e-4] * 3 + [np.radians(0.5) ** 2] * 3, rtol=1e-12)
    # A robot standing still is not pinned with infinite weight.
    still = odometry_covariance(np.array([0.0]), 0.01, np.radians(0.5), min_step_m=0.01)
    np.testing.assert_allclose(np.diag(still[0])[:3], [1e-6] * 3, rtol=1e-12)
    T, _, _ = square_route(0.2)
    edges = temporal_edges(T, 0.01, np.radians(0.5))
    assert len(edges) == len(T) - 1
    L = np.linalg.norm(relative_poses(T)[:, :3, 3], axis=1)
    np.testing.assert_allclose([1.0 / e.information[0, 0] for e in edges], 1e-4 * np.maximum(L, 0.01), rtol=1e-9)


def test_bad_graphs_are_refused():
    poses = np.stack([np.eye(4)] * 3)
    edge = PoseEdge.from_covariance(0, 5, np.eye(4), np.eye(6))
    with pytest.raises(ValueError, match="does not join"):
        optimise_pose_graph(poses, [edge])
    with pytest.raises(ValueError, match="kernel"):
        optimise_pose_graph(poses, [], kernel="tukey")
    with pytest.raises(ValueError, match="fixed pose"):
        optimise_pose_graph(poses, [], fixed=3)
    with pytest.raises(ValueError, match="poses"):
        optimise_pose_graph(np.eye(4), [])
