"""Pose-graph optimisation (fisheye paper III-E): keyframe poses tied by relative-pose edges.

Vertices are the keyframe poses T_wc; an edge (i, j) measures T_ij = T_wi^-1 T_wj, the pose of
keyframe j in keyframe i's frame, with a 6 x 6 information matrix. Temporal edges come from the
odometry, loop-closure edges from images of one place seen on two visits (loop_closure.py). The
graph is solved with gtsam's Levenberg-Marquardt (the paper used g2o; design.md measured both).

Uncertainty convention (pipemap.geometry.se3): the true relative pose is T_ij exp(delta) with
delta = (rho, phi) ~ N(0, covariance), rho a translation and phi a rotation vector, both in the
axes of keyframe j -- the right perturbation the back end uses everywhere. gtsam's Pose3 tangent is
the same perturbation with the blocks in the other order (phi, rho); the swap happens here only.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from pipemap.geometry.se3 import as_rt, compose, invert, to_matrix

# (rho, phi) <-> (phi, rho): the permutation is its own inverse.
_SWAP = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])
_KERNELS = ("huber", "cauchy")


@dataclass(frozen=True)
class PoseEdge:
    """A relative-pose constraint: T_ij = T_wi^-1 T_wj measured, with its information (rho, phi order)."""

    i: int
    j: int
    T_ij: np.ndarray  # (4, 4)
    information: np.ndarray  # (6, 6)
    loop: bool = False  # loop-closure edges may take a robust kernel; temporal edges never do

    @classmethod
    def from_covariance(cls, i: int, j: int, T_ij, covariance, loop: bool = False) -> "PoseEdge":
        return cls(i, j, np.asarray(T_ij, float), np.linalg.inv(np.asarray(covariance, float)), loop)


def relative_poses(poses_T_wc) -> np.ndarray:
    """T_k,k+1 = T_wk^-1 T_w,k+1 of consecutive poses (N, 4, 4) -> (N - 1, 4, 4)."""
    R, t = as_rt(poses_T_wc)
    Ri, ti = invert(R[:-1], t[:-1])
    return to_matrix(*compose(Ri, ti, R[1:], t[1:]))


def odometry_covariance(step_m, translation_sigma_m: float, rotation_sigma_rad: float,
                        min_step_m: float = 0.01) -> np.ndarray:
    """Covariance (..., 6, 6) of odometry steps of length `step_m` (...): variances proportional to length.

    Visual odometry drifts like a random walk in distance driven: each metre adds an independent
    error, so the variance of a step grows linearly with its length and the variance of a stretch
    is the same however it is cut into keyframes. `translation_sigma_m` and `rotation_sigma_rad` are
    the standard deviations after one metre (per sqrt(m)). Steps shorter than `min_step_m` count as
    that long, so that a robot standing still does not pin its poses together with infinite weight.
    """
    length = np.maximum(np.asarray(step_m, float), min_step_m)
    diag = np.array([translation_sigma_m**2] * 3 + [rotation_sigma_rad**2] * 3)
    return length[..., None, None] * np.diag(diag)


def temporal_edges(poses_T_wc, translation_sigma_m: float = 0.01, rotation_sigma_rad: float = np.radians(0.5),
                   min_step_m: float = 0.01) -> list[PoseEdge]:
    """Odometry edges between consecutive poses (N, 4, 4), weighted by `odometry_covariance`."""
    steps = relative_poses(poses_T_wc)
    cov = odometry_covariance(np.linalg.norm(steps[:, :3, 3], axis=1), translation_sigma_m, rotation_sigma_rad,
                              min_step_m)
    return [PoseEdge.from_covariance(k, k + 1, steps[k], cov[k]) for k in range(len(steps))]


def _noise(information: np.ndarray, kernel: str | None, kernel_width: float):
    info = _SWAP @ np.asarray(information, float) @ _SWAP
    base = gtsam.noiseModel.Gaussian.Information(0.5 * (info + info.T))
    if kernel is None:
        return base
    estimator = (gtsam.noiseModel.mEstimator.Huber if kernel == "huber" else gtsam.noiseModel.mEstimator.Cauchy)
    return gtsam.noiseModel.Robust.Create(estimator.Create(kernel_width), base)


def _pose3(T: np.ndarray) -> gtsam.Pose3:
    R, t = as_rt(T)
    # Re-orthonormalise: gtsam rejects rotations that drifted off SO(3) by round-off.
    u, _, vt = np.linalg.svd(R)
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return gtsam.Pose3(gtsam.Rot3(R), gtsam.Point3(*t))


def optimise_pose_graph(poses_T_wc, edges: list[PoseEdge], *, kernel: str | None = "huber",
                        kernel_width: float = 2.0, fixed: int = 0, max_iterations: int = 100) -> np.ndarray:
    """Poses (N, 4, 4) T_wc that best agree with `edges`, pose `fixed` held where it is.

    `kernel` ('huber', 'cauchy' or None) applies to loop-closure edges only, on their whitened
    error (units of standard deviations, `kernel_width` of them), so that a wrong loop closure cannot
    bend the whole map; odometry stays Gaussian. Huber is convex and safe from any start. Cauchy
    gives a wrong closure almost no weight, but it would also ignore a right one whose error is
    still large in the drifted start, so it starts from the Huber solution.
    """
    poses = np.asarray(poses_T_wc, float)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) == 0:
        raise ValueError(f"poses must be (N, 4, 4) with N > 0, got {poses.shape}")
    if kernel is not None and kernel not in _KERNELS:
        raise ValueError(f"unknown robust kernel {kernel!r} (expected one of {', '.join(_KERNELS)} or None)")
    n = len(poses)
    if not 0 <= fixed < n:
        raise ValueError(f"fixed pose {fixed} is not one of the {n} poses")
    for e in edges:
        if not (0 <= e.i < n and 0 <= e.j < n) or e.i == e.j:
            raise ValueError(f"edge ({e.i}, {e.j}) does not join two of the {n} poses")
    values = gtsam.Values()
    for k in range(n):
        values.insert(k, _pose3(poses[k]))
    for stage in (["huber", "cauchy"] if kernel == "cauchy" else [kernel]):
        values = _solve(values, edges, stage, kernel_width, _pose3(poses[fixed]), fixed, max_iterations)
    out = np.stack([values.atPose3(k).matrix() for k in range(n)])
    # The prior holds the fixed pose to 1e-6; move the whole graph rigidly so that it is exact.
    R, t = as_rt(out)
    Rf, tf = invert(R[fixed], t[fixed])
    Ra, ta = compose(*as_rt(poses[fixed]), Rf, tf)
    return to_matrix(*compose(Ra, ta, R, t))


def _solve(initial, edges, kernel, kernel_width, anchor, fixed, max_iterations):
    graph = gtsam.NonlinearFactorGraph()
    for e in edges:
        noise = _noise(e.information, kernel if e.loop else None, kernel_width)
        graph.add(gtsam.BetweenFactorPose3(e.i, e.j, _pose3(e.T_ij), noise))
    graph.add(gtsam.PriorFactorPose3(fixed, anchor, gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    return gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()


__all__ = ["PoseEdge", "relative_poses", "odometry_covariance", "temporal_edges", "optimise_pose_graph"]
