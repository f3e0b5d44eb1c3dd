"""The initial batch of the sparse VO as a bundle adjustment on the wall (2010 report 5.3.2, generalised).

The report's batch (eqs. 45-49, sparse/offset.py) holds every keyframe of the batch at the nominal
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
that the first camera looks up (+Y), the report's convention for R0 (eq. 45). The camera's mount
(mount_of: the angle of its optical axis to the pipe axis, the roll, C_X and C_Y) is reported as the
mean over the batch's keyframes, the robot's wobble averaged, with a covariance carried from the
axis's.

The sliding refinement (5.3.3) uses the same solve over windows of keyframes (`bundle_window`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipemap.backend.bundle import BundleProblem, BundleResult, BundleState, Observations
from pipemap.camera import CameraModel
from pipemap.config import SparseSettings
from pipemap.geometry.cylinder import Cylinder
from pipemap.solvers.schur import solve_damped
from pipemap.straight.sparse.geometry import E_H, wall_points

_S = SparseSettings()  # the defaults are the settings' own


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
    mount: np.ndarray  # (4,) angle and roll (rad), C_X, C_Y (m) (mount_of), mean over the batch's keyframes
    mount_covariance: np.ndarray  # (4, 4) of `mount`
    fit_px: float  # RMS reprojection error of all observations, each capped at 3 Huber widths (compares starts)


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


def oblique(X: np.ndarray, C: np.ndarray, max_incidence_deg: float | None) -> np.ndarray:
    """Whether wall points X (M, 3) in the pipe frame are seen from camera centres C (M, 3) more than
    max_incidence_deg from the wall's normal. Matches there drift along the image's motion as the wall's
    foreshortening changes from keyframe to keyframe, a scale error no wall term corrects (against the
    simulator's truth at a 50 deg mount, registered matches move 0.05 % further than the wall up to 60 deg,
    0.4 % at 60-65 deg, 2 % at 65-70; Harris peaks 0.2 % at 40-55 deg, 1 % at 55-60, 4 % at 65-70)."""
    if max_incidence_deg is None:
        return np.zeros(len(X), bool)
    ray = X - C
    normal = X.copy()
    normal[:, 2] = 0.0  # the pipe frame's h axis is the pipe's
    cos = np.abs(np.sum(ray * normal, axis=1)) / (np.linalg.norm(ray, axis=1) * np.linalg.norm(normal, axis=1))
    return cos < np.cos(np.radians(max_incidence_deg))


def _observed_points(gids, uvs, bearings, R, C, radius, max_incidence_deg):
    """The observations of points seen by at least two keyframes, none of them oblique, and the points' start at
    the mean of their wall estimates from the starting poses: (keyframe, point, pixels, X0) or None."""
    cam, point, pixels, rows = batch_observations(gids, uvs)
    if len(point) == 0:
        return None
    X_all = np.concatenate([wall_points(R[i], C[i], b, radius)[0] for i, b in enumerate(bearings)])[rows]
    ok = np.all(np.isfinite(X_all), axis=1)
    P = int(point.max()) + 1
    sums = np.zeros((P, 3))
    np.add.at(sums, point[ok], X_all[ok])
    n = np.bincount(point[ok], minlength=P)
    if np.any(n == 0):
        return None
    X0 = sums / n[:, None]
    keep = ~oblique(X0[point], C[cam], max_incidence_deg)
    seen = np.bincount(point[keep], minlength=P) >= 2
    keep &= seen[point]
    renumber = np.cumsum(seen) - 1
    return cam[keep], renumber[point[keep]], pixels[keep], X0[seen]


def _solve_on_wall(gids, uvs, bearings, R, C, camera, radius, held: int, wall_sigma_m: float, huber_px: float,
                   mad_k: float, outlier_passes: int, iterations: int, max_incidence_deg: float | None = None):
    """The bundle adjustment on the wall shared by the batch and the windows: keyframe poses (R, C in the pipe
    frame as start; the first `held` of them fixed), wall points and the axis relative to a virtual reference
    camera at the first keyframe's centre looking along the start's axis. (problem, result, points) or None."""
    K = len(gids)
    observed = _observed_points(gids, uvs, bearings, R, C, radius, max_incidence_deg)
    if observed is None:
        return None
    cam, point, pixels, X0 = observed
    P = len(X0)
    if P == 0 or 2 * len(cam) < 6 * (K - held) + 4 + 3 * P:
        return None
    Rp = np.concatenate([R, np.eye(3)[None]])
    tp = np.concatenate([C, C[:1]])
    start = Cylinder(np.zeros(3), E_H, radius)
    problem = BundleProblem(camera, (Rp, tp), X0, Observations(cam, point, pixels),
                            fixed_poses=tuple(range(held)) + (K,), cylinder=start, cylinder_reference=K,
                            tau=1.0 / wall_sigma_m**2, huber_px=huber_px, huber_m=max(50 * wall_sigma_m, 1e-3),
                            mad_k=mad_k, outlier_passes=outlier_passes, max_iterations=iterations)
    res = problem.solve()
    if res.cylinder is None or not np.all(np.isfinite(res.poses)):
        return None
    return problem, res, P


def bundle_window(gids: list[np.ndarray], uvs: list[np.ndarray], bearings: list[np.ndarray], R: np.ndarray,
                  C: np.ndarray, camera: CameraModel, radius: float, held: int, *,
                  wall_sigma_m: float = _S.offset_wall_sigma_m, huber_px: float = _S.offset_huber_px,
                  mad_k: float = _S.offset_mad_k, outlier_passes: int = _S.offset_outlier_passes,
                  iterations: int = _S.offset_batch_iterations,
                  max_incidence_deg: float | None = _S.max_incidence_deg
                  ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The sliding refinement as a bundle adjustment on the wall: the window's keyframes (R (K, 3, 3), C (K, 3) in
    the pipe frame), the first `held` of them fixed where earlier windows left them, the rest free in all six
    degrees of freedom, the points on a wall of the known radius. The wall's axis is free in the solve (no other
    parameterisation of it is on offer), so the free keyframes come out relative to this stretch's axis; they are
    put back relative to the pipe's, which is straight, from the last held keyframe on (`onto_axis`): left where
    the solve put them, windows turn and sink a little each, and the trajectory bent 30 mm off the axis over
    6 m. Returns the new (R, C) and the RMS reprojection error, or None when the window has too little shared
    structure."""
    out = _solve_on_wall(gids, uvs, bearings, R, C, camera, radius, held, wall_sigma_m, huber_px, mad_k,
                         outlier_passes, iterations, max_incidence_deg)
    if out is None:
        return None
    _, res, _ = out
    K = len(gids)
    Rs, Cs = res.poses[:K, :3, :3], res.poses[:K, :3, 3]
    Rn, Cn = onto_axis(res.cylinder, Rs[held:], Cs[held:], Rs[held - 1], Cs[held - 1])
    return np.concatenate([R[:held], Rn]), np.concatenate([C[:held], Cn]), float(res.rms_px)


def onto_axis(cylinder: Cylinder, R: np.ndarray, C: np.ndarray, anchor_R: np.ndarray,
              anchor_C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses (R (K, 3, 3), C (K, 3)) placed relative to `cylinder` as they are, but with its axis moved onto the
    pipe frame's (+h through the origin): the anchor pose keeps its h and the direction round the axis it looks
    in, so the poses go on from it."""
    d = cylinder.direction * (1.0 if cylinder.direction @ E_H >= 0 else -1.0)

    def frame(axis, origin):
        look = anchor_R[:, 2] - (anchor_R[:, 2] @ axis) * axis
        Y = look / np.linalg.norm(look)
        return np.stack([np.cross(Y, axis), Y, axis]), origin + ((anchor_C - origin) @ axis) * axis

    Mw, ow = frame(d, cylinder.origin)
    Mg, og = frame(E_H, np.zeros(3))
    G = Mg.T @ Mw
    return np.einsum("ij,kjl->kil", G, R), (C - ow) @ G.T + og


def bundle_batch(gids: list[np.ndarray], uvs: list[np.ndarray], bearings: list[np.ndarray], R: np.ndarray,
                 C: np.ndarray, camera: CameraModel, radius: float, *,
                 wall_sigma_m: float = _S.offset_wall_sigma_m, huber_px: float = _S.offset_huber_px,
                 mad_k: float = _S.offset_mad_k, outlier_passes: int = _S.offset_outlier_passes,
                 iterations: int = _S.offset_batch_iterations,
                 max_incidence_deg: float | None = _S.max_incidence_deg) -> BatchResult | None:
    """Bundle adjustment of the batch's keyframes (poses R (K, 3, 3), C (K, 3) in the pipe frame as
    start) and wall points, with the pipe axis free relative to the first keyframe. None when the
    batch has too few shared points to constrain its unknowns."""
    out = _solve_on_wall(gids, uvs, bearings, R, C, camera, radius, 1, wall_sigma_m, huber_px, mad_k,
                         outlier_passes, iterations, max_incidence_deg)
    if out is None:
        return None
    problem, res, P = out
    K = len(gids)
    Rk, Ck = res.poses[:K, :3, :3], res.poses[:K, :3, 3]
    Rn, Cn = to_pipe_frame(res.cylinder, Rk, Ck)
    tilt = float(np.arccos(np.clip(abs(res.cylinder.direction @ E_H), 0.0, 1.0)))
    # the poses are solved relative to the held first keyframe, and the axis relative to them: the mount's
    # uncertainty is the axis's, carried through to the mean mount over the batch (the robot's wobble averaged)
    params = res.cylinder.local_params(problem.ref_R, problem.ref_t)

    def mount(p):
        Rm, Cm = to_pipe_frame(Cylinder.from_local(p, problem.ref_R, problem.ref_t, radius), Rk, Ck)
        return np.mean([mount_of(r, c) for r, c in zip(Rm, Cm)], axis=0)

    J = _numeric_jacobian(mount, params)
    axis_cov = axis_covariance(problem, res)
    cov = J @ axis_cov @ J.T if np.all(np.isfinite(axis_cov)) else np.full((4, 4), np.inf)
    sigma = np.sqrt(np.maximum(np.diag(cov)[2:], 0.0))
    return BatchResult(Rn, Cn, Cn[0, :2].copy(), res.rms_px, int(res.inliers.sum()), P, tilt, sigma, mount(params), cov,
                       _capped_rms(problem, res, 3 * huber_px))


def _capped_rms(problem: BundleProblem, res: BundleResult, cap_px: float) -> float:
    """RMS of every observation's reprojection error capped at cap_px: a fit measure that, unlike the inlier RMS,
    does not improve by calling more observations outliers."""
    state = BundleState(res.poses[:, :3, :3], res.poses[:, :3, 3], res.points,
                        res.cylinder.local_params(problem.ref_R, problem.ref_t))
    e = np.linalg.norm(problem.linearise(state, jacobians=False).reproj, axis=1)
    return float(np.sqrt(np.mean(np.minimum(e, cap_px) ** 2)))


def mount_of(R: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(angle, roll, C_X, C_Y) of a camera (R camera -> pipe, C) in the pipe frame: the angle (rad) between its
    optical axis and the pipe axis (+h), the roll (rad) of the pipe axis in the image (0: along image x,
    positive towards image y) and its offset from the axis in the pipe frame turned about the axis so that
    the camera looks towards +Y (the report's R0 convention; the first keyframe defines the frame that way)."""
    d = R[2]  # the pipe axis +h in camera axes
    look = R[:, 2]  # the optical axis in pipe axes
    turn = np.arctan2(-look[0], look[1])  # how far round the axis from +Y it looks
    c, s = np.cos(turn), np.sin(turn)
    return np.array([np.arccos(np.clip(d[2], -1.0, 1.0)), np.arctan2(d[1], d[0]),
                     c * C[0] + s * C[1], -s * C[0] + c * C[1]])


def _numeric_jacobian(f, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((f(x + d) - f(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


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


def axis_covariance(problem: BundleProblem, res: BundleResult) -> np.ndarray:
    """Covariance (4, 4) of the axis parameters (gamma, beta, t_X, t_Y) relative to the reference camera, from the
    inverse of the reduced Gauss-Newton system at the solution, with the keypoint noise taken from the inlier
    reprojection RMS. Columns of the inverse come from the solver's own Schur step with a unit gradient on one
    axis parameter and none elsewhere. Infinite where the system is singular."""
    R, t = res.poses[:, :3, :3], res.poses[:, :3, 3]
    state = BundleState(R, t, res.points, res.cylinder.local_params(R[problem.ref], t[problem.ref]))
    stage = problem.stage(res.inliers)
    eq = problem.normal_equations(state, res.inliers, stage)
    cov = np.empty((4, 4))
    for j in range(4):
        g = np.zeros(len(eq.gx))
        g[j] = -1.0
        step = solve_damped(replace(eq, gc=np.zeros_like(eq.gc), gp=np.zeros_like(eq.gp), gx=g), stage.schur, 0.0)
        if step is None or not step[1][j] > 0:
            return np.full((4, 4), np.inf)
        cov[:, j] = step[1][:4]
    return 0.5 * (cov + cov.T) * max(res.rms_px, 1e-3) ** 2
