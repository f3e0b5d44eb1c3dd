"""The initial batch of the sparse VO as a bundle adjustment on the wall (2010 report 5.3.2, generalised).

The report's batch (eqs. 45-49, sparse_offset.py) holds every keyframe of the batch at the nominal
rotation R0 and a common offset (C_X, C_Y), and lets only C_X, C_Y and the heights h_a move. The
offset is read from the foreshortening of the wall: how the image flow varies across the image
with the distance to the curved wall. With a wide lens close to a small pipe (the report's 6-inch
pipe, 70 deg) that signal is strong; with a narrow lens in a large pipe (16-inch, 25 deg) the wall
seen is nearly flat and the signal is a few per cent of the flow, smaller than the image motion of
a robot that rolls and pitches by a few tenths of a degree between keyframes. Holding those
rotations at R0 then forces the offset to absorb them, and the offset sets the metric scale.

So the batch here estimates what the image actually depends on: a full pose for every keyframe of
the batch, the wall points, and the pipe's axis relative to the first camera (its offset and its
tilt), minimising the image reprojection error of every keypoint (the report's eq. 47 measure, in
the original distorted image) with the points held on the wall of the known radius. It is the
fisheye paper's cylinder-regularised bundle adjustment (pipemap.backend.bundle, III-C) with a stiff
wall prior: the known radius fixes the scale, the first camera fixes the frame.

The axis is parameterised relative to a virtual reference camera at the first keyframe's centre
looking along the pipe (the local parameterisation is singular for an axis across the optical
axis, which is how the report's camera looks). The result is expressed in a pipe frame whose h axis
is the estimated axis, with h = 0 at the first keyframe and the rotation about the axis chosen so
that the first camera looks up (+Y), the report's convention for R0 (eq. 45).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipemap.backend.bundle import BundleProblem, BundleResult, BundleState, Observations
from pipemap.backend.schur import solve_damped
from pipemap.camera import CameraModel
from pipemap.geometry.cylinder import Cylinder
from pipemap.straight.sparse_geometry import E_H, wall_points


@dataclass(frozen=True)
class BatchResult:
    R: np.ndarray  # (K, 3, 3) camera -> pipe axes of the batch's keyframes
    C: np.ndarray  # (K, 3) their centres in the pipe frame; C[0, 2] = 0
    offset: np.ndarray  # (C_X, C_Y) of the first keyframe
    rms_px: float  # RMS reprojection error of the inlier observations
    observations: int  # inlier observations used
    points: int  # wall points seen by at least two keyframes
    tilt_rad: float  # angle between the estimated axis and the start's
    offset_sigma: np.ndarray  # (2,) standard deviations of (C_X, C_Y) from the Gauss-Newton covariance


def batch_observations(gids: list[np.ndarray], uvs: list[np.ndarray]):
    """Observations of the points seen by at least two keyframes: (keyframe (M,), point (M,), pixels (M, 2),
    row (M,) into the concatenated keypoints) with points numbered 0 .. P-1."""
    k = np.concatenate([np.full(len(g), i) for i, g in enumerate(gids)])
    g = np.concatenate(gids)
    uv = np.concatenate(uvs).reshape(-1, 2)
    ids, inverse, counts = np.unique(g, return_inverse=True, return_counts=True)
    keep = counts[inverse] >= 2
    _, point = np.unique(inverse[keep], return_inverse=True)
    return k[keep], point, uv[keep], np.flatnonzero(keep)


def bundle_batch(gids: list[np.ndarray], uvs: list[np.ndarray], bearings: list[np.ndarray], R: np.ndarray,
                 C: np.ndarray, camera: CameraModel, radius: float, *, wall_sigma_m: float = 1e-4,
                 huber_px: float = 1.0, mad_k: float = 3.0, outlier_passes: int = 3,
                 iterations: int = 50) -> BatchResult | None:
    """Bundle adjustment of the batch's keyframes (poses R (K, 3, 3), C (K, 3) in the pipe frame as
    start) and wall points, with the pipe axis free relative to the first keyframe. None when the
    batch has too few shared points to constrain its unknowns."""
    K = len(gids)
    cam, point, pixels, rows = batch_observations(gids, uvs)
    P = int(point.max()) + 1 if len(point) else 0
    if P == 0 or 2 * len(cam) < 6 * (K - 1) + 4 + 3 * P:
        return None
    # start the points at the mean of their wall estimates from the starting poses
    X_all = np.concatenate([wall_points(R[i], C[i], b, radius)[0] for i, b in enumerate(bearings)])[rows]
    ok = np.all(np.isfinite(X_all), axis=1)
    sums = np.zeros((P, 3))
    np.add.at(sums, point[ok], X_all[ok])
    n = np.bincount(point[ok], minlength=P)
    if np.any(n == 0):
        return None
    X0 = sums / n[:, None]
    # the virtual reference (index K): the first keyframe's centre, camera z along the start's axis
    Rp = np.concatenate([R, np.eye(3)[None]])
    tp = np.concatenate([C, C[:1]])
    start = Cylinder(np.zeros(3), E_H, radius)
    problem = BundleProblem(camera, (Rp, tp), X0, Observations(cam, point, pixels), fixed_poses=(0, K),
                            cylinder=start, cylinder_reference=K, tau=1.0 / wall_sigma_m**2, huber_px=huber_px,
                            huber_m=max(50 * wall_sigma_m, 1e-3), mad_k=mad_k, outlier_passes=outlier_passes,
                            max_iterations=iterations)
    res = problem.solve()
    if res.cylinder is None or not np.all(np.isfinite(res.poses)):
        return None
    sigma = axis_offset_sigma(problem, res)
    Rk, Ck = res.poses[:K, :3, :3], res.poses[:K, :3, 3]
    Rn, Cn = to_pipe_frame(res.cylinder, Rk, Ck)
    tilt = float(np.arccos(np.clip(abs(res.cylinder.direction @ E_H), 0.0, 1.0)))
    return BatchResult(Rn, Cn, Cn[0, :2].copy(), res.rms_px, int(res.inliers.sum()), P, tilt, sigma)


def to_pipe_frame(cylinder: Cylinder, R: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses (R (K, 3, 3), C (K, 3)) re-expressed in the pipe frame of `cylinder`: h along its axis
    (the sense of the old h), h = 0 at C[0], and the first camera's optical axis in the (Y, h) plane
    on the +Y side, as the report's R0 has it."""
    d = cylinder.direction * (1.0 if cylinder.direction @ E_H >= 0 else -1.0)
    origin = cylinder.origin + ((C[0] - cylinder.origin) @ d) * d
    look = R[0][:, 2] - (R[0][:, 2] @ d) * d
    y = look / np.linalg.norm(look)
    M = np.stack([np.cross(y, d), y, d])  # rows: the new X, Y, h in the old pipe frame
    return np.einsum("ij,kjl->kil", M, R), (C - origin) @ M.T


def axis_offset_sigma(problem: BundleProblem, res: BundleResult) -> np.ndarray:
    """Standard deviations (2,) of the axis offset (t_X, t_Y) relative to the reference camera -- the first
    keyframe's (C_X, C_Y) -- from the inverse of the reduced Gauss-Newton system at the solution, with the
    keypoint noise taken from the inlier reprojection RMS. Columns of the inverse come from the solver's
    own Schur step with a unit gradient on one axis parameter and none elsewhere."""
    R, t = res.poses[:, :3, :3], res.poses[:, :3, 3]
    state = BundleState(R, t, res.points, res.cylinder.local_params(R[problem.ref], t[problem.ref]))
    stage = problem.stage(res.inliers)
    eq = problem.normal_equations(state, res.inliers, stage)
    out = np.full(2, np.inf)
    for j in (2, 3):
        g = np.zeros(len(eq.gx))
        g[j] = -1.0
        step = solve_damped(replace(eq, gc=np.zeros_like(eq.gc), gp=np.zeros_like(eq.gp), gx=g), stage.schur, 0.0)
        if step is not None and step[1][j] > 0:
            out[j - 2] = np.sqrt(step[1][j]) * max(res.rms_px, 1e-3)
    return out
