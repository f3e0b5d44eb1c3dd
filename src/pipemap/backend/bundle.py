"""Sliding-window sparse bundle adjustment with a local straight-cylinder prior (fisheye paper III-C).

Minimises, over camera poses T_wc, points X and (optionally) one cylinder of known radius r,

    eps = sum_obs huber_px(|u' - u|) + tau * sum_points huber_m(d_i),                  (eq. 2, 3, 6)

where u' is the fisheye projection of X into its camera (pixels) and d_i = sqrt(X~^2 + Y~^2) - r is
the signed distance of point i from the cylinder wall in the paper's 4-DOF parameterisation relative
to the window's first ("reference") pose (eq. 4-5, `pipemap.geometry.cylinder`). Huber costs are
minimised by iteratively re-weighted Levenberg-Marquardt with analytic Jacobians and the Schur
complement on the points (`pipemap.solvers.schur`). Outliers: after each of `outlier_passes` stages of
LM, observations whose signed Huber-weighted errors sqrt(w) (u - u') lie more than
max(mad_k * 1.4826 MAD, huber_px) from their median are set aside (and may come back at a later pass).

A bent axis (`bend_knot_m`, `pipemap.geometry.bend`): the wall distance is taken from the straight
axis plus offsets at knots every `bend_knot_m` along it, and the bend prior's squared residuals join
eps. Pipe runs sag and kink at their joints by millimetres; a straight cylinder over a window of a
few metres then pulls points and poses onto a straight line, which tilts the trajectory.

An axis prior (`axis_prior`: a direction and its sigma in radians) holds the cylinder's (gamma, beta) to that
direction's; bench_window_ends.py uses it to show that a window's end keyframes turn even with the true axis.

Gauge: the poses in `fixed_poses` (default the first) are held. With the cylinder (tau > 0) its known
radius fixes the scale, so one fixed pose is a complete gauge. With tau = 0 the scale is free: hold a
second pose, or pass `fixed_distance=(i, j)` to keep |t_j - t_i| at its initial value (a stiff prior,
1 px^2 per `1 / distance_weight` metres); otherwise LM's damping merely keeps the scale where it started.

The cylinder's reference frame is the reference pose's value at the start of the solve. Under the
default gauge that pose is fixed, which is exactly the paper's parameterisation; if it is free, the
parameters stay relative to its initial value (the same family of cylinders, so the same optimum).

Pose updates are right perturbations (rho, phi) in camera axes, see `pipemap.geometry.se3`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from pipemap.camera.base import CameraModel
from pipemap.config import BundleSettings
from pipemap.geometry.bend import AxisKnots
from pipemap.geometry.cylinder import Cylinder, CylinderFit, distance_jacobians, local_distance, local_frame
from pipemap.geometry.rotations import skew
from pipemap.geometry.se3 import as_rt, retract, to_matrix, world_to_camera
from pipemap.solvers.robust import huber_cost, huber_weights, mad_inliers
from pipemap.solvers.schur import BlockSummer, NormalEquations, SchurStructure, solve_damped, transposed
from pipemap.solvers.staged_lm import solve_in_stages

_B = BundleSettings()  # the problems' defaults are the settings' own



def _single_threaded_blas():
    """Multi-threaded OpenBLAS stalls for up to 0.5 s per call on a loaded 2-core machine, and the
    reduced system (~600 unknowns) gains nothing from threads: hold BLAS to one thread while
    solving."""
    return threadpool_limits(1, user_api="blas")


@dataclass(frozen=True)
class Observations:
    """Feature observations: point `point[k]` seen by keyframe `camera[k]` at pixel `pixels[k]`."""

    camera: np.ndarray  # (K,) int
    point: np.ndarray  # (K,) int
    pixels: np.ndarray  # (K, 2)

    def __post_init__(self):
        cam = np.asarray(self.camera).astype(np.int64).reshape(-1)
        pt = np.asarray(self.point).astype(np.int64).reshape(-1)
        uv = np.asarray(self.pixels, float)
        if uv.shape != (len(cam), 2) or pt.shape != cam.shape:
            raise ValueError(f"observations disagree: camera {cam.shape}, point {pt.shape}, pixels {uv.shape}")
        object.__setattr__(self, "camera", cam)
        object.__setattr__(self, "point", pt)
        object.__setattr__(self, "pixels", uv)

    def __len__(self) -> int:
        return len(self.camera)


def problem_inputs(poses, points, observations):
    """Checked (R, t, points, Observations) of a bundle problem: poses (N, 4, 4) or an (R, t) pair,
    points (M, 3), observations indexing both."""
    R, t = as_rt(poses)
    X = np.array(points, dtype=float)
    if R.ndim != 3 or X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"expected poses (N, 4, 4) and points (M, 3), got {R.shape[:-2]} poses, points {X.shape}")
    obs = observations if isinstance(observations, Observations) else Observations(*observations)
    N, M = len(R), len(X)
    if len(obs) and (obs.camera.min() < 0 or obs.camera.max() >= N or obs.point.min() < 0 or obs.point.max() >= M):
        raise ValueError("observation indices out of range")
    return R, t, X, obs


@dataclass
class BundleState:
    """The unknowns: poses T_wc = (R, t), points, and the cylinder's local parameters (or None)."""

    R: np.ndarray  # (N, 3, 3)
    t: np.ndarray  # (N, 3)
    points: np.ndarray  # (M, 3)
    # (gamma, beta, t_X, t_Y[, bend offsets (K, 2) raveled]) relative to the frozen reference
    cylinder: np.ndarray | None

    def retract(self, pose_delta: np.ndarray, point_delta: np.ndarray, cylinder_delta=None) -> "BundleState":
        R, t = retract(self.R, self.t, pose_delta)
        cyl = None if self.cylinder is None else self.cylinder + (0.0 if cylinder_delta is None else cylinder_delta)
        return BundleState(R, t, self.points + point_delta, cyl)


@dataclass
class Linearisation:
    """Residuals and analytic Jacobians at one state (all observations, all points)."""

    reproj: np.ndarray  # (K, 2) u' - u, pixels
    J_pose: np.ndarray  # (K, 2, 6) d u' / d (rho, phi) of the observing camera
    J_point: np.ndarray  # (K, 2, 3) d u' / d X
    dist: np.ndarray | None  # (M,) signed distance to the cylinder wall, metres
    Jd_point: np.ndarray | None  # (M, 3)
    Jd_cyl: np.ndarray | None  # (M, 4)


@dataclass
class BundleResult:
    poses: np.ndarray  # (N, 4, 4) T_wc
    points: np.ndarray  # (M, 3)
    cylinder: Cylinder | None  # in world coordinates
    cylinder_params: np.ndarray | None  # (gamma, beta, t_X, t_Y) relative to the final reference pose
    inliers: np.ndarray  # (K,) bool per observation
    point_inliers: np.ndarray  # (M,) bool: seen in at least two inlier observations
    cost_history: list[float]  # eps at the start and after every iteration (the inlier set changes between stages)
    iterations: int
    time_s: float
    rms_px: float  # RMS reprojection error of the inliers
    cylinder_rms_m: float  # RMS distance of the inlier points to the cylinder (nan without one)
    converged: bool
    outlier_counts: list[int] = field(default_factory=list)  # outliers after each MAD pass
    # The bent axis: knots along the cylinder frame's z (relative to the reference pose at the start
    # of the solve) and offsets (K, 2) in that frame's x and y; None for a straight cylinder.
    bend: tuple[AxisKnots, np.ndarray] | None = None


def _taken(arrays, keep: np.ndarray):
    """The rows `keep` (bool) of each array: the arrays themselves when it keeps every row."""
    return arrays if keep.all() else tuple(a[keep] for a in arrays)


def _camera_blocks(schur: SchurStructure, w: np.ndarray, e: np.ndarray, Jc: np.ndarray, Jp: np.ndarray):
    """U (C, 6, 6), gc (C, 6) and W (Kf, 6, 3) of the observations by free cameras: weights w, residuals e, pose and
    point Jacobians Jc, Jp."""
    wJc = w[:, None, None] * Jc
    U = schur.cam_runs(lambda i: transposed(wJc[i]) @ Jc[i], (6, 6))
    gc = schur.to_cam(np.einsum("kai,ka->ki", wJc, e))
    return U, gc, np.swapaxes(wJc, 1, 2) @ Jp


class BundleProblem:
    """One window of sparse bundle adjustment; `solve()` runs it.

    poses: (N, 4, 4) T_wc or an (R, t) pair; points: (M, 3) world; observations: `Observations` or a
    (camera, point, pixels) triple. cylinder: a `Cylinder`, a `CylinderFit` or None; it is parameterised
    relative to pose `cylinder_reference`; `cylinder_points` (M,) bool restricts the prior to some points.
    """

    def __init__(self, camera: CameraModel, poses, points, observations, *, fixed_poses=(0,),
                 cylinder: Cylinder | CylinderFit | None = None, cylinder_reference: int = 0,
                 cylinder_points: np.ndarray | None = None, tau: float = _B.tau, huber_px: float = _B.huber_px,
                 huber_m: float = _B.huber_m, mad_k: float = _B.mad_k, outlier_passes: int = _B.outlier_passes,
                 max_iterations: int = _B.max_iterations,
                 fixed_distance: tuple[int, int] | None = None, distance_weight: float = 1e6,
                 bend_knot_m: float | None = None, bend_kink_deg: float = _B.bend_kink_deg,
                 bend_offset_mm: float = _B.bend_offset_mm, bend_sag_mm: float = _B.bend_sag_mm,
                 axis_prior: tuple[np.ndarray, float] | None = None, observation_sigma: np.ndarray | None = None):
        self.camera = camera
        R, t, X, obs = problem_inputs(poses, points, observations)
        N, M = len(R), len(X)
        self.obs, self.N, self.M = obs, N, M
        # each observation's pixel error in units of the nominal one: its residual and Jacobian are divided by it
        self.sigma = np.ones(len(obs)) if observation_sigma is None else np.asarray(observation_sigma, float)
        if self.sigma.shape != (len(obs),) or not np.all(self.sigma > 0):
            raise ValueError(f"observation_sigma must be ({len(obs)},) and positive")
        self.fixed = np.zeros(N, bool)
        self.fixed[list(fixed_poses)] = True
        self.free_index = np.full(N, -1)
        self.free_index[~self.fixed] = np.arange(int((~self.fixed).sum()))
        self.tau, self.huber_px, self.huber_m = float(tau), float(huber_px), float(huber_m)
        self.mad_k, self.outlier_passes, self.max_iterations = float(mad_k), int(outlier_passes), int(max_iterations)
        self.fixed_distance = None if fixed_distance is None else (int(fixed_distance[0]), int(fixed_distance[1]))
        self.distance_weight = float(distance_weight)
        if self.fixed_distance is not None:
            i, j = self.fixed_distance
            self.distance0 = float(np.linalg.norm(t[j] - t[i]))
        self.ref = int(cylinder_reference)
        self.ref_R, self.ref_t = R[self.ref].copy(), t[self.ref].copy()
        if isinstance(cylinder, CylinderFit):
            cylinder = cylinder.cylinder
        self.radius = None if cylinder is None else cylinder.radius
        cyl0 = None if cylinder is None else cylinder.local_params(self.ref_R, self.ref_t)
        self.cylinder_points = np.ones(M, bool) if cylinder_points is None else np.asarray(cylinder_points, bool)
        self.knots, self.bend_prior = None, None
        if cyl0 is not None and bend_knot_m is not None and self.cylinder_points.any():
            Rt, tt = local_frame(cyl0)
            z = (world_to_camera(self.ref_R, self.ref_t, X[self.cylinder_points]) @ Rt.T + tt)[:, 2]
            pad = 0.01 * float(bend_knot_m)  # no point on an end knot, where the slope of the offset jumps to 0
            self.knots = AxisKnots.spanning(float(z.min()) - pad, float(z.max()) + pad, float(bend_knot_m))
            # Cylinder frame x ~ the reference camera's x (across, level), y ~ its y (down, for a crawler).
            P = self.knots.prior(2, np.radians(bend_kink_deg), 1e-3 * np.array([bend_offset_mm, bend_sag_mm]))
            self.bend_prior = np.hstack([np.zeros((len(P), 4)), P])
            cyl0 = np.concatenate([cyl0, np.zeros(2 * len(self.knots))])
        self.axis_prior = None
        if cyl0 is not None and axis_prior is not None:
            # the prior's direction in the same (gamma, beta) as the cylinder's, over its sigma (radians)
            d, sigma = np.asarray(axis_prior[0], float), float(axis_prior[1])
            ab = Cylinder(self.ref_t, d, self.radius).local_params(self.ref_R, self.ref_t)[:2]
            self.axis_prior = (ab, 1.0 / sigma)
        self.initial = BundleState(R, t, X, cyl0)

    @classmethod
    def from_settings(cls, camera, poses, points, observations, settings, **kwargs) -> "BundleProblem":
        """Take tau, the Huber thresholds, mad_k, outlier_passes and max_iterations from `Settings.bundle`."""
        b = getattr(settings, "bundle", settings)
        opts = dict(tau=b.tau, huber_px=b.huber_px, huber_m=b.huber_m, mad_k=b.mad_k,
                    outlier_passes=b.outlier_passes, max_iterations=b.max_iterations,
                    bend_knot_m=b.bend_knot_m, bend_kink_deg=b.bend_kink_deg, bend_offset_mm=b.bend_offset_mm,
                    bend_sag_mm=b.bend_sag_mm)
        opts.update(kwargs)
        return cls(camera, poses, points, observations, **opts)

    @property
    def uses_cylinder(self) -> bool:
        return self.initial.cylinder is not None and self.tau > 0

    # -- residuals and Jacobians ----------------------------------------------------------------

    def linearise(self, state: BundleState, jacobians: bool = True) -> Linearisation:
        cam, pt = self.obs.camera, self.obs.point
        Rc = state.R[cam]
        Xc = world_to_camera(Rc, state.t[cam], state.points[pt])
        if not jacobians:
            uv = self.camera.project(Xc)[0]
            dist = None
            if self.uses_cylinder:
                Xm = world_to_camera(self.ref_R, self.ref_t, state.points)
                dist = local_distance(Xm, state.cylinder, self.radius, jacobians=False, knots=self.knots)
            return Linearisation(uv - self.obs.pixels, None, None, dist, None, None)
        uv, Jproj, _ = self.camera.project_jacobian(Xc)
        J_pose = np.empty((len(cam), 2, 6))
        J_pose[:, :, :3] = -Jproj
        J_pose[:, :, 3:] = Jproj @ skew(Xc)
        J_point = Jproj @ transposed(Rc)
        dist = Jd_point = Jd_cyl = None
        if self.uses_cylinder:
            dist, Jd_point, Jd_cyl, _ = distance_jacobians(state.points, state.cylinder, self.ref_R, self.ref_t,
                                                           self.radius, knots=self.knots)
        return Linearisation(uv - self.obs.pixels, J_pose, J_point, dist, Jd_point, Jd_cyl)

    def _active_points(self, inliers: np.ndarray) -> np.ndarray:
        return np.bincount(self.obs.point[inliers], minlength=self.M) > 0

    def cost(self, state: BundleState, inliers: np.ndarray, lin: Linearisation | None = None) -> float:
        """eps = sum huber_px(|u' - u|) + tau sum huber_m(|d|) over inlier observations and active points."""
        lin = lin or self.linearise(state, jacobians=False)
        c = float(huber_cost(np.linalg.norm(lin.reproj[inliers], axis=1) / self.sigma[inliers], self.huber_px).sum())
        if lin.dist is not None:
            on = self._active_points(inliers) & self.cylinder_points
            c += self.tau * float(huber_cost(np.abs(lin.dist[on]), self.huber_m).sum())
            if self.bend_prior is not None:
                c += float(np.sum((self.bend_prior @ state.cylinder) ** 2))
            if self.axis_prior is not None:
                c += float(np.sum(self._axis_residual(state) ** 2))
        if self.fixed_distance is not None:
            c += self._distance_prior(state)[0] ** 2
        return c

    def _axis_residual(self, state: BundleState) -> np.ndarray:
        """(gamma, beta) of the axis off the prior's direction, over its sigma."""
        ab, w = self.axis_prior
        return w * (state.cylinder[:2] - ab)

    def _distance_prior(self, state: BundleState):
        """Residual s (|t_j - t_i| - d0) and its derivative with respect to (rho_i, rho_j)."""
        i, j = self.fixed_distance
        v = state.t[j] - state.t[i]
        L = np.linalg.norm(v)
        u = v / L
        s = self.distance_weight
        return s * (L - self.distance0), -s * (u @ state.R[i]), s * (u @ state.R[j])

    def stage(self, inliers: np.ndarray) -> "_Stage":
        """The sparsity structure of the inlier observations (reused while they do not change)."""
        return _Stage(self, inliers)

    def normal_equations(self, state: BundleState, inliers: np.ndarray,
                         stage: "_Stage | None" = None) -> NormalEquations:
        """IRLS-weighted Gauss-Newton blocks at `state` over the inlier observations."""
        st = stage if stage is not None else self.stage(inliers)
        lin = self.linearise(state)
        # Views where every observation counts, and each per-observation array let go once summed: a section solved
        # whole has 300,000 observations, and these arrays held together had set its peak.
        e, Jc, Jp = _taken((lin.reproj, lin.J_pose, lin.J_point), inliers)
        lin = Linearisation(None, None, None, lin.dist, lin.Jd_point, lin.Jd_cyl)
        s = self.sigma[inliers]
        w = huber_weights(np.linalg.norm(e, axis=1) / s, self.huber_px) / (s * s)
        wJp = w[:, None, None] * Jp
        V = st.to_point(transposed(wJp) @ Jp)
        gp = st.to_point(np.einsum("kai,ka->ki", wJp, e))
        del wJp
        U, gc, W = _camera_blocks(st.schur, *_taken((w, e, Jc, Jp), st.on))
        del e, Jc, Jp
        C = st.schur.C
        q = len(state.cylinder) if self.uses_cylinder else 0
        Ux, gx, Wx_rank1 = np.zeros((q, q)), np.zeros(q), (np.zeros((self.M, q)), np.zeros((self.M, 3)))
        active = st.active
        if q:
            on_cyl = active & self.cylinder_points
            wd = np.where(on_cyl, self.tau * huber_weights(np.abs(lin.dist), self.huber_m), 0.0)
            V += np.einsum("m,mi,mj->mij", wd, lin.Jd_point, lin.Jd_point)
            gp += (wd * lin.dist)[:, None] * lin.Jd_point
            wJd = wd[:, None] * lin.Jd_cyl
            Ux = wJd.T @ lin.Jd_cyl
            gx = lin.Jd_cyl.T @ (wd * lin.dist)
            Wx_rank1 = (wJd, lin.Jd_point)
            if self.bend_prior is not None:
                Ux += self.bend_prior.T @ self.bend_prior
                gx += self.bend_prior.T @ (self.bend_prior @ state.cylinder)
            if self.axis_prior is not None:
                w = self.axis_prior[1]
                Ux[:2, :2] += w * w * np.eye(2)
                gx[:2] += w * self._axis_residual(state)
        # Points without inlier observations are frozen: an identity block with no gradient.
        V[~active] = np.eye(3)
        gp[~active] = 0.0
        eq = NormalEquations(U, gc, V, gp, W, st.schur.obs_cam, st.schur.obs_pt, Ux, gx, None,
                             Wx_rank1=Wx_rank1)
        if self.fixed_distance is not None:
            r, Ji, Jj = self._distance_prior(state)
            J = np.zeros(6 * C + q)
            for k, Jk in ((self.fixed_distance[0], Ji), (self.fixed_distance[1], Jj)):
                if self.free_index[k] >= 0:
                    J[6 * self.free_index[k]: 6 * self.free_index[k] + 3] += Jk
            eq.H_extra, eq.g_extra = np.outer(J, J), J * r
        return eq

    # -- the solver ---------------------------------------------------------------------------

    def _step(self, state: BundleState, delta) -> BundleState:
        dc, dx, dp = delta
        pose_delta = np.zeros((self.N, 6))
        pose_delta[~self.fixed] = dc
        return state.retract(pose_delta, dp, dx if len(dx) else None)

    def _reject(self, state: BundleState, inliers: np.ndarray) -> np.ndarray:
        e = self.linearise(state, jacobians=False).reproj / self.sigma[:, None]
        a = np.linalg.norm(e, axis=1)
        weighted = np.sqrt(huber_weights(a, self.huber_px))[:, None] * e
        return mad_inliers(weighted, self.mad_k, reference=inliers, floor=self.huber_px) & np.all(np.isfinite(e), 1)

    def solve(self) -> BundleResult:
        """Levenberg-Marquardt in stages separated by MAD outlier passes; see the module docstring."""
        with _single_threaded_blas():
            return self._solve()

    def _solve(self) -> BundleResult:
        t0 = time.perf_counter()
        cache: dict = {}

        def linearise(state, inliers):
            if cache.get("inliers") is not inliers:  # the sparsity structure holds for a whole stage
                cache.update(inliers=inliers, stage=self.stage(inliers))
            return self.normal_equations(state, inliers, cache["stage"]), cache["stage"]

        run = solve_in_stages(
            self.initial, np.all(np.isfinite(self.obs.pixels), axis=1),
            cost=self.cost, linearise=linearise, solve=lambda eq, lam: solve_damped(eq[0], eq[1].schur, lam),
            step=self._step, reject=self._reject, same=np.array_equal, outliers=lambda inl: (~inl).sum(),
            max_iterations=self.max_iterations, outlier_passes=self.outlier_passes)
        return self._result(run.state, run.context, run.cost_history, run.iterations, time.perf_counter() - t0,
                            run.converged, run.outlier_counts)

    def _result(self, state, inliers, history, iterations, seconds, converged, counts) -> BundleResult:
        lin = self.linearise(state, jacobians=False)
        rms = float(np.sqrt(np.mean(np.sum(lin.reproj[inliers] ** 2, axis=1)))) if inliers.any() else float("nan")
        point_in = np.bincount(self.obs.point[inliers], minlength=self.M) >= 2
        cyl = params = None
        cyl_rms = float("nan")
        bend = None
        if state.cylinder is not None:
            cyl = Cylinder.from_local(state.cylinder[:4], self.ref_R, self.ref_t, self.radius)
            params = cyl.local_params(state.R[self.ref], state.t[self.ref])
            d = lin.dist[point_in & self.cylinder_points] if lin.dist is not None else np.zeros(0)
            cyl_rms = float(np.sqrt(np.mean(d**2))) if d.size else float("nan")
            if self.knots is not None:
                bend = (self.knots, state.cylinder[4:].reshape(-1, 2).copy())
        return BundleResult(to_matrix(state.R, state.t), state.points.copy(), cyl, params, inliers, point_in,
                            history, iterations, seconds, rms, cyl_rms, converged, counts, bend)


class _Stage:
    """Index structure of one inlier set: which observations, their free cameras, the summing operators."""

    def __init__(self, problem: BundleProblem, inliers: np.ndarray):
        self.cam, self.pt = problem.obs.camera[inliers], problem.obs.point[inliers]
        f = problem.free_index[self.cam]
        self.on = f >= 0
        self.active = np.bincount(self.pt, minlength=problem.M) > 0
        self.to_point = BlockSummer(self.pt, problem.M)
        self.schur = SchurStructure(f[self.on], self.pt[self.on], int((~problem.fixed).sum()), problem.M)


def solve_window(camera: CameraModel, poses, points, observations, settings=None, **kwargs) -> BundleResult:
    """Convenience: build a `BundleProblem` (from `Settings.bundle` when given) and solve it."""
    if settings is not None:
        return BundleProblem.from_settings(camera, poses, points, observations, settings, **kwargs).solve()
    return BundleProblem(camera, poses, points, observations, **kwargs).solve()


__all__ = ["Observations", "BundleState", "BundleProblem", "BundleResult", "Linearisation", "solve_window"]
