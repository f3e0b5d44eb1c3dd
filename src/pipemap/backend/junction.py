"""Bundle adjustment of a T-intersection with the two-cylinder tee model (fisheye paper III-D).

The red section ends at pose P_r, the blue one starts at P_b; each was mapped on its own, and C_r,
C_b are cylinders fitted to their ends relative to P_r and P_b (`fit_end_cylinders`). This solve
optimises the poses P_T of the tee span between them, the points and the tee parameters
Phi = (zeta_r, l_r, zeta_b, l_b, phi) (`pipemap.geometry.tee`), minimising the cost of eq. 2-6:

    eps = sum_obs huber_px(|u' - u|) + tau * sum_points huber_m(d_i),

d_i being the signed distance of point i to the wall of the cylinder it is assigned to: the one whose
surface is nearer (|d| smallest), re-assigned at the start of every stage between outlier passes.
A point far from both walls is on neither pipe (a stub's end cap, a valve, a fitting) and would pull
Phi towards it through the Huber cost's constant gradient, so the sum runs over the points whose
distance to the nearer wall passes the same MAD rule as the straight sections' cylinder fits
(within mad_k robust sigmas, at least the Huber threshold), renewed with the assignment.
Both cylinders are infinite in the model, so the branch's cylinder continued past I crosses the far
wall of the pipe that runs through the junction; when the points show which pipe that is, the branch
cylinder is cut at I for the assignment (`JunctionProblem.through_pipe`).
The red side is held: P_r and any `fixed` poses. P_b and any `attached` poses (the blue section's
first keyframes, whose poses relative to P_b are known from its own solve) move with Phi as
T_wc(P_r) Q(Phi) S_j, S_j being their initial pose relative to P_b; their observations tie the blue
side in. The red cylinder is fixed with P_r; the blue one follows Phi (its world place is
T_wc(P_r) inv(C_r) D(Phi)), so the tee's cylinder terms constrain Phi as well as the points.

As in `pipemap.backend.bundle`: Huber costs by iteratively re-weighted Levenberg-Marquardt with
analytic Jacobians, the points eliminated by the Schur complement (Phi is the small global block),
and MAD outlier passes between stages on the Huber-weighted signed reprojection errors.
Pose updates are right perturbations (rho, phi) in camera axes.

An elbow (`torus_points`, `bend_radius`): its straight pipes are the two cylinders, and the wall of its bend
between them is a torus whose axis is the arc of bend radius rho tangent to both cylinders' axes
(`pipemap.backend.elbow`). Its points join the wall term with their distance to that torus, and rho joins
Phi in the global block: the bend's wall, which the camera sees for as long as it takes the turn, then
holds the angle between the pipes and the poses through the turn, where the reprojections alone let
the rotation drift (0.3 deg over a 30 deg sweeping bend, 10 mm at its vertex). The torus distance's
derivatives by X are its unit normal; by Phi and rho they are taken by central differences (six numbers).
With `free_red_axis` the red cylinder's four parameters join the global block too (their derivatives by
central differences as well): the pipe before the elbow is fitted to its wall and the bend's as this solve sees
them, instead of held at the straight section's end fit. A short straight between two bends takes its heading
from the previous elbow's solve, and errors of a tenth of a degree each (its last keyframes' turn, its end
cylinder, the previous turn) left it 0.3 deg off its own bend on elbow-cross route A seed 2: 9 mm at the
sweeping bend's vertex, 0.54 % of Table I; with the axis free, 0.04 %.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from pipemap.backend.bundle import problem_inputs
from pipemap.backend.elbow import bend_normals, bend_residuals, model_bend
from pipemap.backend.end_cylinders import fit_end_cylinder, fit_end_cylinders
from pipemap.camera.base import CameraModel
from pipemap.config import BundleSettings
from pipemap.errors import PipemapError
from pipemap.geometry.cylinder import Cylinder, CylinderFit
from pipemap.geometry.rotations import skew
from pipemap.geometry.se3 import as_rt, compose, invert, retract, to_matrix, world_to_camera
from pipemap.geometry.tee import TeeModel, adjoint_of_inverse
from pipemap.solvers.robust import huber_cost, huber_weights, mad_inliers
from pipemap.solvers.schur import BlockSummer, NormalEquations, SchurStructure, solve_damped, transposed
from pipemap.solvers.staged_lm import solve_in_stages

_B = BundleSettings()  # the problems' defaults are the settings' own

_PHI_RIDGE = 1e-9  # keeps the reduced system definite when nothing observes some part of Phi
_THROUGH_MIN_POINTS = 20  # points beyond the junction that show a pipe running on through it


@dataclass
class JunctionState:
    R: np.ndarray  # (N, 3, 3) T_wc of every camera (attached ones follow `model`)
    t: np.ndarray  # (N, 3)
    points: np.ndarray  # (M, 3)
    model: TeeModel
    rho: float = float("nan")  # an elbow's bend radius (nan for a tee)


@dataclass
class JunctionResult:
    poses: np.ndarray  # (N, 4, 4) T_wc: held poses unchanged, the tee span solved, attached ones moved with the tee
    points: np.ndarray  # (M, 3)
    model: TeeModel  # Phi (canonical: phi in [0, pi)) with C_r, C_b relative to P_r, P_b
    intersection: np.ndarray  # (3,) I in the world
    blue_pose: np.ndarray  # (4, 4) the new T_wc of P_b
    blue_transform: np.ndarray  # (4, 4) world transform that takes the blue section's initial poses to the solved ones
    on_blue: np.ndarray  # (M,) bool: point assigned to the blue cylinder (final assignment)
    on_wall: np.ndarray  # (M,) bool: point on its cylinder's wall, in the cylinder term (final)
    through: str | None  # the pipe taken to run on through the junction ("red", "blue") or None
    inliers: np.ndarray  # (K,) bool per observation
    point_inliers: np.ndarray  # (M,) bool: seen in at least two inlier observations
    cost_history: list[float]
    iterations: int
    time_s: float
    rms_px: float  # RMS reprojection error of the inlier observations
    cylinder_rms_m: float  # RMS distance of the inlier points to their cylinder
    converged: bool
    outlier_counts: list[int] = field(default_factory=list)
    bend_radius_m: float = float("nan")  # an elbow's, solved with Phi

    @property
    def params(self) -> np.ndarray:
        return self.model.params


def _local_params(cyl, R, t, what: str):
    """(eq. 4 parameters relative to the end pose (R, t), radius or None). A world `Cylinder` is taken in the
    frame of the poses; a `CylinderFit`'s parameters are relative to its own reference pose, which is the
    end pose (`fit_end_cylinder`), whatever frame its section was mapped in."""
    if isinstance(cyl, CylinderFit):
        return np.array(cyl.params, float), cyl.cylinder.radius
    if isinstance(cyl, Cylinder):
        return cyl.local_params(R, t), cyl.radius
    p = np.asarray(cyl, float).reshape(-1)
    if p.shape != (4,) or not np.all(np.isfinite(p)):
        raise ValueError(f"the {what} cylinder must be a Cylinder, a CylinderFit or 4 finite parameters")
    return p, None


class JunctionProblem:
    """One T-intersection solve; `solve()` runs it. See the module docstring.

    poses: (N, 4, 4) T_wc initial guesses (or an (R, t) pair); points (M, 3); observations: `Observations`
    or a (camera, point, pixels) triple.
    red / blue: C_r, C_b as eq. 4 parameters relative to P_r / P_b; as `CylinderFit`s from
    `fit_end_cylinder` (parameters relative to their reference pose, taken to be P_r / P_b, so each section
    may have been mapped in its own frame); or as world `Cylinder`s in the frame of `poses` (expressed
    relative to the initial poses[red_pose] / poses[blue_pose]).
    fixed: further held poses (the red section's); attached: further poses carried with P_b (the blue
    section's).
    through: which pipe runs on through the junction ("red", "blue"), None for the paper's plain
    nearest-surface assignment, or "auto" to decide from the initial points (`through_pipe`).
    model: a starting Phi (a `TeeModel` or 5 numbers); by default it comes from the initial P_r, P_b and
    the cylinders.
    """

    def __init__(self, camera: CameraModel, poses, points, observations, red, blue, *, red_pose: int,
                 blue_pose: int, fixed=(), attached=(), radius: float | None = None, model=None,
                 cylinder_points: np.ndarray | None = None, torus_points: np.ndarray | None = None,
                 bend_radius: float | None = None, free_red_axis: bool = False, through: str | None = "auto",
                 angle: float | None = None, tau: float = _B.tau,
                 huber_px: float = _B.huber_px, huber_m: float = _B.huber_m, mad_k: float = _B.mad_k,
                 outlier_passes: int = _B.outlier_passes, max_iterations: int = _B.max_iterations):
        self.camera = camera
        R, t, X, obs = problem_inputs(poses, points, observations)
        N, M = len(R), len(X)
        self.obs, self.N, self.M = obs, N, M
        self.red_index, self.blue_index = int(red_pose), int(blue_pose)
        fixed_mask = np.zeros(N, bool)
        fixed_mask[[self.red_index, *fixed]] = True
        att_mask = np.zeros(N, bool)
        att_mask[[self.blue_index, *attached]] = True
        if np.any(fixed_mask & att_mask):
            raise ValueError("a pose cannot be both held with P_r and attached to P_b")
        self.fixed = fixed_mask
        self.free_index = np.full(N, -1)
        free = ~fixed_mask & ~att_mask
        self.free_index[free] = np.arange(int(free.sum()))
        self.n_free = int(free.sum())
        self.attached = np.flatnonzero(att_mask)
        self.attached_index = np.full(N, -1)
        self.attached_index[self.attached] = np.arange(len(self.attached))
        self.tau, self.huber_px, self.huber_m = float(tau), float(huber_px), float(huber_m)
        self.mad_k, self.outlier_passes, self.max_iterations = float(mad_k), int(outlier_passes), int(max_iterations)
        self.cylinder_points = np.ones(M, bool) if cylinder_points is None else np.asarray(cylinder_points, bool)
        self.torus_points = np.zeros(M, bool) if torus_points is None else np.asarray(torus_points, bool)
        self.elbow = bend_radius is not None and bool(self.torus_points.any())
        if self.elbow and np.any(self.torus_points & self.cylinder_points):
            raise ValueError("a point cannot be on a straight pipe's wall and on the bend's")
        self.free_red = self.elbow and bool(free_red_axis)
        self.n_global = (10 if self.free_red else 6) if self.elbow else 5

        Rr, tr, Rb, tb = R[self.red_index], t[self.red_index], R[self.blue_index], t[self.blue_index]
        red_p, r1 = _local_params(red, Rr, tr, "red")
        blue_p, r2 = _local_params(blue, Rb, tb, "blue")
        r = radius if radius is not None else (r1 if r1 is not None else r2)
        if r is None:
            raise PipemapError("the junction solve needs the pipe radius when the cylinders are given as parameters")
        if model is None:
            tee = TeeModel.from_poses((Rr, tr), (Rb, tb), red_p, blue_p, r)
        elif isinstance(model, TeeModel):
            tee = TeeModel(model.params, red_p, blue_p, r)
        else:
            tee = TeeModel(model, red_p, blue_p, r)
        # A held angle: phi leaves the global block and stays at its value.
        self.held = np.zeros(self.n_global, bool)
        if angle is not None:
            if not 0.0 <= float(angle) < np.pi:
                raise ValueError(f"a held angle must lie in [0, pi), got {angle!r}")
            params = tee.canonical().params.copy()
            params[4] = float(angle)
            tee = tee.with_params(params)
            self.held[4] = True
        # Attached poses relative to P_b, and how a perturbation of Q moves each of them.
        self.blue_initial = to_matrix(Rb, tb)
        S_R, S_t = compose(*invert(Rb, tb), R[self.attached], t[self.attached])
        self.S_R, self.S_t = S_R, S_t
        self.S_adjoint = np.stack([adjoint_of_inverse((a, b)) for a, b in zip(S_R, S_t)])
        self.initial = self._attach(JunctionState(R, t, X, tee, float(bend_radius) if self.elbow else float("nan")))
        if through not in ("auto", "red", "blue", None):
            raise ValueError(f"through must be 'auto', 'red', 'blue' or None, got {through!r}")
        self.through = None
        self.through = self.through_pipe(self.initial) if through == "auto" else through

    @classmethod
    def from_settings(cls, camera, poses, points, observations, red, blue, settings, **kwargs) -> "JunctionProblem":
        """tau, the Huber thresholds, mad_k, outlier_passes and max_iterations from `Settings.bundle`."""
        b = getattr(settings, "bundle", settings)
        opts = dict(tau=b.tau, huber_px=b.huber_px, huber_m=b.huber_m, mad_k=b.mad_k,
                    outlier_passes=b.outlier_passes, max_iterations=b.max_iterations)
        opts.update(kwargs)
        return cls(camera, poses, points, observations, red, blue, **opts)

    # -- state ----------------------------------------------------------------------------------

    def _attach(self, state: JunctionState) -> JunctionState:
        """Place P_b and the attached poses from P_r and Phi."""
        R, t = state.R.copy(), state.t.copy()
        Rb, tb = as_rt(state.model.blue_pose((R[self.red_index], t[self.red_index])))
        R[self.attached], t[self.attached] = compose(Rb, tb, self.S_R, self.S_t)
        return JunctionState(R, t, state.points, state.model, state.rho)

    def _step(self, state: JunctionState, delta) -> JunctionState:
        dc, dx, dp = delta
        dx = np.where(self.held, 0.0, dx)
        pose_delta = np.zeros((self.N, 6))
        pose_delta[self.free_index >= 0] = dc
        R, t = retract(state.R, state.t, pose_delta)
        model = state.model.with_params(state.model.params + dx[:5])
        if self.free_red:
            model = TeeModel(model.params, model.red + dx[6:10], model.blue, model.radius)
        rho = state.rho + dx[5] if self.elbow else state.rho
        return self._attach(JunctionState(R, t, state.points + dp, model, rho))

    # -- residuals and Jacobians -------------------------------------------------------------------

    def assign(self, state: JunctionState) -> np.ndarray:
        """(M,) bool: the point's nearer cylinder surface is the blue one; with a known through pipe, the
        branch's cylinder ends at I (see `through_pipe`)."""
        red_pose = self._red_pose(state)
        d_red, d_blue = state.model.distances(state.points, red_pose, jacobians=False)
        on_blue = np.abs(d_blue) < np.abs(d_red)
        if self.through is not None:
            a_red, a_blue = state.model.axial(state.points, red_pose)
            if self.through == "red":  # the blue pipe is the branch: nothing of it lies behind I
                on_blue &= a_blue >= 0
            else:
                on_blue |= a_red > 0
        return on_blue

    def wall_inliers(self, state: JunctionState, on_blue: np.ndarray,
                     reference: np.ndarray | None = None) -> np.ndarray:
        """(M,) bool: the point lies on the wall of its cylinder (see the module docstring); `reference`: the
        previous stage's wall points, over which the median and MAD are taken."""
        d = self.wall_distance(state, on_blue)
        walls = self.cylinder_points | self.torus_points if self.elbow else self.cylinder_points
        ref = walls if reference is None else reference
        return mad_inliers(d, self.mad_k, reference=ref, floor=self.huber_m) & walls

    def _wall_context(self, state: JunctionState, reference: np.ndarray | None = None):
        on_blue = self.assign(state)
        return on_blue, self.wall_inliers(state, on_blue, reference)

    def through_pipe(self, state: JunctionState) -> str | None:
        """Which pipe runs on through the junction: "red", "blue" or None (not seen, or both).

        Evidence: points on a cylinder's wall and off the other's, beyond the junction on that cylinder's
        far side (more than 1.5 radii past I). The branch's cylinder continued past I crosses the through
        pipe's far wall, where the nearest-surface rule alone would pull wall points seen at grazing angles
        onto it."""
        red_pose = self._red_pose(state)
        d_red, d_blue = state.model.distances(state.points, red_pose, jacobians=False)
        a_red, a_blue = state.model.axial(state.points, red_pose)
        r, tol = state.model.radius, 4 * self.huber_m
        seen = np.bincount(self.obs.point, minlength=self.M) > 0
        red = int(np.sum(seen & (a_red > 1.5 * r) & (np.abs(d_red) < tol) & (np.abs(d_blue) > tol)))
        blue = int(np.sum(seen & (a_blue < -1.5 * r) & (np.abs(d_blue) < tol) & (np.abs(d_red) > tol)))
        if max(red, blue) >= _THROUGH_MIN_POINTS and max(red, blue) >= 4 * min(red, blue):
            return "red" if red > blue else "blue"
        return None

    def _red_pose(self, state):
        return state.R[self.red_index], state.t[self.red_index]

    def reprojection(self, state: JunctionState) -> np.ndarray:
        cam, pt = self.obs.camera, self.obs.point
        Xc = world_to_camera(state.R[cam], state.t[cam], state.points[pt])
        return self.camera.project(Xc)[0] - self.obs.pixels

    def cylinder_distance(self, state: JunctionState, on_blue: np.ndarray) -> np.ndarray:
        d_red, d_blue = state.model.distances(state.points, self._red_pose(state), jacobians=False)
        return np.where(on_blue, d_blue, d_red)

    def wall_distance(self, state: JunctionState, on_blue: np.ndarray) -> np.ndarray:
        """Each point's distance to its wall: its cylinder's, or an elbow's bend's torus."""
        d = self.cylinder_distance(state, on_blue)
        if self.elbow:
            d[self.torus_points] = self.torus_distance(state, self.torus_points)
        return d

    def torus_distance(self, state: JunctionState, which: np.ndarray, jacobians: bool = False):
        """Distances of the points `which` to the bend's wall; with jacobians also d/dX (n, 3) and
        d/d(Phi, rho) (n, 6)."""
        red_pose = self._red_pose(state)
        X = state.points[which]

        def dist(model: TeeModel, rho: float) -> np.ndarray:
            return bend_residuals(X, model_bend(model, red_pose), rho, model.radius)[0]

        d = dist(state.model, state.rho)
        if not jacobians:
            return d
        J_X = bend_normals(X, model_bend(state.model, red_pose), state.rho)
        g = self.n_global
        J_g = np.empty((len(X), g))
        for i, eps in enumerate(((1e-6,) * 5 + (1e-7,) + (1e-6,) * 4)[:g]):
            step = np.zeros(g)
            step[i] = eps
            plus = dist(*self._moved(state, step))
            minus = dist(*self._moved(state, -step))
            J_g[:, i] = (plus - minus) / (2 * eps)
        return d, J_X, J_g

    def _moved(self, state: JunctionState, step: np.ndarray) -> tuple[TeeModel, float]:
        """(model, rho) after a step in the global block."""
        m = state.model
        red = m.red + step[6:10] if self.free_red else m.red
        return TeeModel(m.params + step[:5], red, m.blue, m.radius), state.rho + step[5]

    def _red_axis_jacobian(self, state: JunctionState, on_blue: np.ndarray) -> np.ndarray:
        """(M, 4) d (wall distance of each point's cylinder) / d C_r, by central differences."""
        red_pose = self._red_pose(state)
        def dist(step: np.ndarray) -> np.ndarray:
            d_red, d_blue = self._moved(state, step)[0].distances(state.points, red_pose, jacobians=False)
            return np.where(on_blue, d_blue, d_red)

        J = np.empty((self.M, 4))
        for i in range(4):
            step = np.zeros(self.n_global)
            step[6 + i] = 1e-6
            J[:, i] = (dist(step) - dist(-step)) / 2e-6
        return J

    def cost(self, state: JunctionState, inliers: np.ndarray, on_blue: np.ndarray, on_wall: np.ndarray) -> float:
        e = self.reprojection(state)[inliers]
        c = float(huber_cost(np.linalg.norm(e, axis=1), self.huber_px).sum())
        if self.tau > 0:
            on = (np.bincount(self.obs.point[inliers], minlength=self.M) > 0) & on_wall
            d = self.wall_distance(state, on_blue)[on]
            c += self.tau * float(huber_cost(np.abs(d), self.huber_m).sum())
        return c

    def normal_equations(self, state: JunctionState, stage: "_Stage", on_blue: np.ndarray,
                         on_wall: np.ndarray) -> NormalEquations:
        """IRLS-weighted Gauss-Newton blocks: free cameras, Phi (the global block), points."""
        st = stage
        Rc = state.R[st.cam]
        Xc = world_to_camera(Rc, state.t[st.cam], state.points[st.pt])
        uv, Jproj, _ = self.camera.project_jacobian(Xc)
        e = uv - self.obs.pixels[st.inliers]
        w = huber_weights(np.linalg.norm(e, axis=1), self.huber_px)
        J_pose = np.concatenate([-Jproj, Jproj @ skew(Xc)], axis=2)  # (K, 2, 6)
        J_point = Jproj @ transposed(Rc)
        wJp = w[:, None, None] * J_point
        V = st.to_point(transposed(wJp) @ J_point)
        gp = st.to_point(np.einsum("kai,ka->ki", wJp, e))
        on = st.on
        wJc = w[on, None, None] * J_pose[on]
        U = st.schur.to_cam(np.swapaxes(wJc, 1, 2) @ J_pose[on])
        gc = st.schur.to_cam(np.einsum("kai,ka->ki", wJc, e[on]))
        W = np.swapaxes(wJc, 1, 2) @ J_point[on]
        # Observations by attached cameras depend on Phi through Q.
        JQ, JQ_red, _ = state.model.q_jacobian()  # (6, 5), (6, 4)
        if self.elbow:  # rho moves no camera
            JQ = np.concatenate([JQ, np.zeros((6, 1))] + ([JQ_red] if self.free_red else []), axis=1)
        a = st.att
        J_tee = J_pose[a] @ (self.S_adjoint[self.attached_index[st.cam[a]]] @ JQ)  # (Ka, 2, n_global)
        g = self.n_global
        wJt = w[a, None, None] * J_tee
        Ux = wJt.reshape(-1, g).T @ J_tee.reshape(-1, g)
        gx = wJt.reshape(-1, g).T @ e[a].reshape(-1)
        Wx = st.to_point_att(np.swapaxes(wJt, 1, 2) @ J_point[a])
        if self.tau > 0:
            d_red, d_blue, Jr_X, Jb_X, Jb_phi = state.model.distances(state.points, self._red_pose(state))
            d = np.where(on_blue, d_blue, d_red)
            Jd_X = np.where(on_blue[:, None], Jb_X, Jr_X)
            Jd_phi = np.where(on_blue[:, None], Jb_phi, 0.0)
            if self.elbow:
                Jd_phi = np.concatenate([Jd_phi, np.zeros((self.M, 1))]
                                        + ([self._red_axis_jacobian(state, on_blue)] if self.free_red else []), axis=1)
                tor = self.torus_points
                d[tor], Jd_X[tor], Jd_phi[tor] = self.torus_distance(state, tor, jacobians=True)
            wd = np.where(st.active & on_wall, self.tau * huber_weights(np.abs(d), self.huber_m), 0.0)
            wJd = wd[:, None] * Jd_X
            V += wJd[:, :, None] * Jd_X[:, None, :]
            gp += d[:, None] * wJd
            Ux += (wd[:, None] * Jd_phi).T @ Jd_phi
            gx += Jd_phi.T @ (wd * d)
            Wx += Jd_phi[:, :, None] * wJd[:, None, :]
        if self.held.any():  # a held parameter: no row, no column, no gradient (the ridge keeps its step at zero)
            Ux[self.held, :], Ux[:, self.held], gx[self.held], Wx[:, self.held] = 0.0, 0.0, 0.0, 0.0
        # Points without inlier observations are frozen: an identity block with no gradient.
        V[~st.active] = np.eye(3)
        gp[~st.active] = 0.0
        Wx[~st.active] = 0.0
        eq = NormalEquations(U, gc, V, gp, W, st.schur.obs_cam, st.schur.obs_pt, Ux, gx, Wx)
        n = 6 * self.n_free + g
        eq.H_extra = np.zeros((n, n))
        eq.H_extra[np.arange(6 * self.n_free, n), np.arange(6 * self.n_free, n)] = _PHI_RIDGE * (1.0 + np.abs(Ux).max())
        eq.g_extra = np.zeros(n)
        return eq

    # -- the solver -------------------------------------------------------------------------------

    def _reject(self, state: JunctionState, inliers: np.ndarray) -> np.ndarray:
        e = self.reprojection(state)
        a = np.linalg.norm(e, axis=1)
        weighted = np.sqrt(huber_weights(a, self.huber_px))[:, None] * e
        return mad_inliers(weighted, self.mad_k, reference=inliers, floor=self.huber_px) & np.all(np.isfinite(e), 1)

    def solve(self) -> JunctionResult:
        """Levenberg-Marquardt in stages separated by MAD outlier passes and cylinder re-assignment."""
        # As in bundle.py: threaded BLAS only stalls on the small reduced system.
        with threadpool_limits(1, user_api="blas"):
            return self._solve()

    def _solve(self) -> JunctionResult:
        t0 = time.perf_counter()
        state = self.initial
        cache: dict = {}

        def linearise(state, ctx):
            if cache.get("ctx") is not ctx:  # the sparsity structure holds for a whole stage
                cache.update(ctx=ctx, stage=_Stage(self, ctx[0]))
            return self.normal_equations(state, cache["stage"], *ctx[1:]), cache["stage"]

        # The context of a stage: the inlier observations, each point's cylinder and whether it lies on that
        # cylinder's wall, all renewed between stages.
        run = solve_in_stages(
            state, (np.all(np.isfinite(self.obs.pixels), axis=1), *self._wall_context(state)),
            cost=lambda st, ctx: self.cost(st, *ctx), linearise=linearise,
            solve=lambda eq, lam: solve_damped(eq[0], eq[1].schur, lam), step=self._step,
            reject=lambda st, ctx: (self._reject(st, ctx[0]), *self._wall_context(st, ctx[2])),
            same=lambda a, b: all(np.array_equal(x, y) for x, y in zip(a, b)),
            outliers=lambda ctx: (~ctx[0]).sum(), max_iterations=self.max_iterations,
            outlier_passes=self.outlier_passes)
        inliers, on_blue, on_wall = run.context
        return self._result(run.state, inliers, on_blue, on_wall, run.cost_history, run.iterations,
                            time.perf_counter() - t0, run.converged, run.outlier_counts)

    def _result(self, state, inliers, on_blue, on_wall, history, iterations, seconds, converged,
                counts) -> JunctionResult:
        e = self.reprojection(state)[inliers]
        rms = float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) if len(e) else float("nan")
        point_in = np.bincount(self.obs.point[inliers], minlength=self.M) >= 2
        d = self.wall_distance(state, on_blue)[point_in & on_wall]
        cyl_rms = float(np.sqrt(np.mean(d**2))) if d.size else float("nan")
        red_pose = self._red_pose(state)
        poses = to_matrix(state.R, state.t)
        blue = poses[self.blue_index]
        return JunctionResult(poses, state.points.copy(), state.model.canonical(), state.model.intersection(red_pose),
                              blue, blue @ np.linalg.inv(self.blue_initial), on_blue, on_wall, self.through, inliers,
                              point_in, history, iterations, seconds, rms, cyl_rms, converged, counts, state.rho)


class _Stage:
    """Index structure of one inlier set: free-camera, attached-camera and all observations."""

    def __init__(self, problem: JunctionProblem, inliers: np.ndarray):
        self.inliers = inliers
        self.cam, self.pt = problem.obs.camera[inliers], problem.obs.point[inliers]
        f = problem.free_index[self.cam]
        self.on = f >= 0
        self.att = problem.attached_index[self.cam] >= 0
        self.active = np.bincount(self.pt, minlength=problem.M) > 0
        self.to_point = BlockSummer(self.pt, problem.M)
        self.to_point_att = BlockSummer(self.pt[self.att], problem.M)
        self.schur = SchurStructure(f[self.on], self.pt[self.on], problem.n_free, problem.M)


def solve_junction(camera: CameraModel, poses, points, observations, red, blue, *, red_pose: int, blue_pose: int,
                   settings=None, **kwargs) -> JunctionResult:
    """Build a `JunctionProblem` (tau, Huber thresholds and outlier passes from `Settings.bundle` when
    given) and solve it. See `JunctionProblem` for the arguments."""
    kwargs.update(red_pose=red_pose, blue_pose=blue_pose)
    if settings is not None:
        return JunctionProblem.from_settings(camera, poses, points, observations, red, blue, settings, **kwargs).solve()
    return JunctionProblem(camera, poses, points, observations, red, blue, **kwargs).solve()


__all__ = ["JunctionProblem", "JunctionResult", "JunctionState", "solve_junction", "fit_end_cylinder",
           "fit_end_cylinders"]
