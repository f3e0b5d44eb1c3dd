"""T-intersection bundle adjustment on a synthetic tee seen by a 190 deg fisheye.

The scene: a straight "red" pipe (radius 0.2 m) with a branch ("blue") leaving it at a right angle at
I. The crawler rides 5 cm below the axes, wobbling, and turns into the branch along a 0.2 m-radius arc.
The red section's last keyframes (P_r among them) are held, the tee span is free, the blue section's
first keyframes (P_b among them) are attached to P_b with their true relative poses. Wall points of both
pipes (none inside the other pipe) are tracked over 3-8 keyframes with 0.5 px noise and 5 % gross
outliers (5-40 px). C_r and C_b are fitted to noisy wall points of the two sections' ends. The initial
guess: the tee span 3 % too long and perturbed (0.5 deg, 3 mm), the blue side displaced by 2 cm and 2 deg,
the points off by 5 mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from pipemap.backend.bundle import Observations
from pipemap.backend.junction import JunctionProblem, _Stage, fit_end_cylinder, fit_end_cylinders, solve_junction
from pipemap.config import Settings
from pipemap.errors import PipemapError
from pipemap.geometry.cylinder import Cylinder
from pipemap.geometry.rotations import exp_so3, log_so3, look_rotation
from pipemap.geometry.se3 import as_rt, to_matrix
from pipemap.geometry.tee import TeeModel
from pipemap.sim.presets import fisheye_camera

from tracks import tracked_runs

RADIUS = 0.2
G = exp_so3(np.array([0.2, -0.4, 0.3]))  # the scene's placement in the world
g = np.array([1.0, 2.0, -0.5])


@dataclass
class TeeScene:
    camera: object
    R: np.ndarray  # (N, 3, 3) true T_wc
    t: np.ndarray
    points: np.ndarray  # (M, 3) true
    on_blue: np.ndarray  # (M,) true pipe of each point
    obs: Observations
    outlier: np.ndarray  # (K,) gross outliers
    red_pose: int
    blue_pose: int
    fixed: np.ndarray  # further held poses (red section)
    attached: np.ndarray  # further attached poses (blue section)
    red_fit: object  # CylinderFit relative to P_r
    blue_fit: object  # ... relative to P_b
    I: np.ndarray
    R0: np.ndarray  # initial guess
    t0: np.ndarray
    points0: np.ndarray
    on_cap: np.ndarray  # (M,) points on a stub's end plate (on neither pipe)


def _path(s, red_len=0.3, arc_r=0.2):
    """Centre-line of the crawler's turn (local frame: red axis x, branch axis y, I at 0) at arc lengths s."""
    arc_len = 0.5 * np.pi * arc_r
    p, h = np.zeros((len(s), 3)), np.zeros((len(s), 3))
    a = s < red_len
    p[a] = np.c_[-arc_r - red_len + s[a], 0 * s[a], 0 * s[a]]
    h[a] = [1, 0, 0]
    b = (s >= red_len) & (s < red_len + arc_len)
    ang = (s[b] - red_len) / arc_r
    p[b] = np.c_[-arc_r + arc_r * np.sin(ang), arc_r - arc_r * np.cos(ang), 0 * ang]
    h[b] = np.c_[np.cos(ang), np.sin(ang), 0 * ang]
    c = s >= red_len + arc_len
    p[c] = np.c_[0 * s[c], arc_r + s[c] - red_len - arc_len, 0 * s[c]]
    h[c] = [0, 1, 0]
    return p, h


def _wall_points(n, rng, red_end=0.6):
    """About n points on the red wall (x in [-1.2, red_end]) and the branch wall (y in [0, 1.0]), uniform over
    the area, none inside the other pipe (the hole into the branch, the branch's mouth)."""
    n_r = int(round(n * 1.8 / 2.8))
    x, a = rng.uniform(-1.2, red_end, n_r), rng.uniform(-np.pi, np.pi, n_r)
    red = np.c_[x, RADIUS * np.cos(a), RADIUS * np.sin(a)]
    red = red[~((red[:, 1] > 0) & (np.hypot(red[:, 0], red[:, 2]) < RADIUS))]
    y, a = rng.uniform(0.0, 1.0, n - n_r), rng.uniform(-np.pi, np.pi, n - n_r)
    blue = np.c_[RADIUS * np.cos(a), y, RADIUS * np.sin(a)]
    blue = blue[np.hypot(blue[:, 1], blue[:, 2]) >= RADIUS]
    return np.r_[red, blue], np.r_[np.zeros(len(red), bool), np.ones(len(blue), bool)]


def _cap_points(n, x, rng):
    """n points on a closed end plate across the red pipe at x: on neither cylinder."""
    rho, a = RADIUS * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(-np.pi, np.pi, n)
    return np.c_[np.full(n, x), rho * np.cos(a), rho * np.sin(a)]


def make_tee_scene(n_points=3500, n_red=5, n_tee=40, n_blue=5, seed=0, noise_px=0.5, outlier_frac=0.05,
                   scale0=1.03, blue_shift=0.02, blue_turn_deg=2.0, cap_at=None, n_cap=0) -> TeeScene:
    """cap_at: the red pipe ends at x = cap_at past I in a closed stub whose end plate carries n_cap points
    (labelled neither red nor blue: `TeeScene.on_cap`)."""
    rng = np.random.default_rng(seed)
    cam = fisheye_camera(640, 480)
    N = n_red + n_tee + n_blue
    total = 0.3 + 0.5 * np.pi * 0.2 + 0.3
    s = np.linspace(0.0, total, N)
    centre, heading = _path(s)
    k = np.arange(N)
    side = np.cross(heading, [0, 0, 1.0])
    wave = lambda amp, period, f=np.sin: amp * f(2 * np.pi * k / period)  # noqa: E731
    c = centre + np.c_[0 * k, 0 * k, wave(0.01, 23, np.cos) - 0.05] + wave(0.015, 17)[:, None] * side
    fwd = heading + wave(0.03, 13)[:, None] * side + np.c_[0 * k, 0 * k, wave(0.02, 19, np.cos)]
    R = look_rotation(fwd, np.array([0, 0, 1.0])) @ exp_so3(np.c_[0 * k, 0 * k, 0.05 * np.sin(2 * np.pi * k / 29)])
    R, t = G @ R, c @ G.T + g
    X, on_blue = _wall_points(n_points, rng, 0.6 if cap_at is None else cap_at)
    on_cap = np.zeros(len(X), bool)
    if cap_at is not None and n_cap:
        X = np.r_[X, _cap_points(n_cap, cap_at, rng)]
        on_blue, on_cap = np.r_[on_blue, np.zeros(n_cap, bool)], np.r_[on_cap, np.ones(n_cap, bool)]
    X = X @ G.T + g
    # Observations: each point along a run of 3-8 consecutive keyframes that see it.
    cams, pts, pix, used = tracked_runs(cam, R, t, X, rng)
    X, on_blue, on_cap = X[used], on_blue[used], on_cap[used]
    pix = pix + rng.normal(0.0, noise_px, pix.shape)
    outlier = rng.random(len(pix)) < outlier_frac
    ang = rng.uniform(0, 2 * np.pi, outlier.sum())
    pix[outlier] += rng.uniform(5, 40, outlier.sum())[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    red_pose, blue_pose = n_red - 1, n_red + n_tee
    # End cylinders from noisy wall points of the two sections (1 mm), as the straight-section solves give them.
    wall, wall_blue = _wall_points(3000, rng)
    wall = wall @ G.T + g + rng.normal(0, 0.001, wall.shape)
    red_fit = fit_end_cylinder((R[:n_red], t[:n_red]), wall[~wall_blue], RADIUS, end="last")
    blue_fit = fit_end_cylinder((R[blue_pose:], t[blue_pose:]), wall[wall_blue], RADIUS, end="first")
    # Initial guess: the red side is right, the tee span too long and perturbed, the blue side displaced rigidly.
    R0, t0 = R.copy(), t.copy()
    tee = slice(n_red, blue_pose)
    t0[tee] = t[red_pose] + scale0 * (t[tee] - t[red_pose]) + rng.normal(0, 0.003, (n_tee, 3))
    R0[tee] = R[tee] @ exp_so3(rng.normal(0, np.radians(0.5), (n_tee, 3)))
    turn = exp_so3(np.radians(blue_turn_deg) * (G @ np.array([0.6, 0.0, 0.8])))
    move = G @ (blue_shift * np.array([0.8, 0.36, -0.48]))
    blue = slice(blue_pose, N)
    R0[blue] = turn @ R[blue]
    t0[blue] = (t[blue] - t[blue_pose]) @ turn.T + t[blue_pose] + move
    X0 = t[red_pose] + scale0 * (X - t[red_pose]) + rng.normal(0, 0.005, X.shape)
    return TeeScene(cam, R, t, X, on_blue, Observations(cams, pts, pix), outlier, red_pose, blue_pose,
                    np.arange(n_red - 1), np.arange(blue_pose + 1, N), red_fit, blue_fit, g.copy(), R0, t0, X0, on_cap)


def solve(sc: TeeScene, **kwargs):
    opts = dict(red_pose=sc.red_pose, blue_pose=sc.blue_pose, fixed=sc.fixed, attached=sc.attached,
                settings=Settings())
    opts.update(kwargs)
    return solve_junction(sc.camera, (sc.R0, sc.t0), sc.points0, sc.obs, sc.red_fit, sc.blue_fit, **opts)


def pose_errors(res, sc):
    R, t = as_rt(res.poses)
    pos = np.linalg.norm(t - sc.t, axis=1)
    rot = np.degrees(np.linalg.norm(log_so3(np.swapaxes(sc.R, 1, 2) @ R), axis=1))
    return pos, rot


@pytest.fixture(scope="module")
def scene() -> TeeScene:
    return make_tee_scene()


@pytest.fixture(scope="module")
def solved(scene):
    return solve(scene)


def test_end_cylinders_are_the_true_pipes(scene):
    sc = scene
    for fit, direction, origin_on_axis in ((sc.red_fit, G @ [1, 0, 0.0], g), (sc.blue_fit, G @ [0, 1, 0.0], g)):
        assert np.degrees(np.arccos(abs(fit.cylinder.direction @ direction))) < 0.3
        assert np.linalg.norm(np.cross(fit.cylinder.origin - origin_on_axis, direction)) < 0.002
    # Parameters are relative to the section's end poses: P_r (last of red) and P_b (first of blue).
    assert np.allclose(sc.red_fit.reference[1], sc.t[sc.red_pose])
    assert np.allclose(sc.blue_fit.reference[1], sc.t[sc.blue_pose])


def test_junction_recovers_the_tee_and_the_poses(scene, solved):
    sc, res = scene, solved
    truth = TeeModel.from_poses((sc.R[sc.red_pose], sc.t[sc.red_pose]), (sc.R[sc.blue_pose], sc.t[sc.blue_pose]),
                                sc.red_fit.params, sc.blue_fit.params, RADIUS)
    start = JunctionProblem(sc.camera, (sc.R0, sc.t0), sc.points0, sc.obs, sc.red_fit, sc.blue_fit,
                            red_pose=sc.red_pose, blue_pose=sc.blue_pose).initial
    start_I = start.model.intersection((sc.R0[sc.red_pose], sc.t0[sc.red_pose]))
    assert np.linalg.norm(start_I - sc.I) > 0.012  # the start is well off
    assert np.linalg.norm(start.t[sc.blue_pose] - sc.t[sc.blue_pose]) > 0.015
    assert np.linalg.norm(res.intersection - sc.I) < 0.002
    assert res.model.angle_deg == pytest.approx(90.0, abs=0.3)
    assert np.abs(res.params[[1, 3]] - truth.params[[1, 3]]).max() < 0.002
    pos, rot = pose_errors(res, sc)
    assert pos.max() < 0.0015 and np.median(pos) < 0.0006
    # 0.5 px is 0.2 deg at this lens's 145 px/rad: the chain of 40 keyframes ends within a few tenths of that.
    assert rot.max() < 0.25 and np.median(rot) < 0.1
    # P_r and the red section held; the blue section moved rigidly with P_b.
    assert np.array_equal(res.poses[: sc.red_pose + 1], to_matrix(sc.R0, sc.t0)[: sc.red_pose + 1])
    moved = res.blue_transform @ to_matrix(sc.R0, sc.t0)[sc.blue_pose:]
    assert np.abs(moved - res.poses[sc.blue_pose:]).max() < 1e-12
    assert np.abs(res.blue_pose - res.poses[sc.blue_pose]).max() < 1e-15
    # Points and fit quality.
    ok = res.point_inliers
    assert np.median(np.linalg.norm(res.points[ok] - sc.points[ok], axis=1)) < 0.002
    assert res.rms_px < 0.75 and res.cylinder_rms_m < 0.001  # 0.5 px per axis: 0.71 px RMS
    assert res.converged and res.cost_history[-1] < 0.05 * res.cost_history[0]


def test_outliers_are_found(scene, solved):
    flagged = ~solved.inliers
    recall = (flagged & scene.outlier).sum() / scene.outlier.sum()
    false = (flagged & ~scene.outlier).sum() / (~scene.outlier).sum()
    assert recall > 0.9 and false < 0.03


def test_points_are_assigned_to_their_pipe(scene, solved):
    sc, res = scene, solved
    # Away from the intersection curve (where a point lies on both walls) the nearer wall is the true one.
    tee = res.model
    d_r, d_b = tee.distances(sc.points, res.poses[sc.red_pose], jacobians=False)
    clear = np.minimum(np.abs(d_r), np.abs(d_b)) < 0.003
    clear &= np.abs(np.abs(d_r) - np.abs(d_b)) > 0.01
    assert clear.sum() > 0.5 * len(sc.points)
    assert np.mean(res.on_blue[clear] == sc.on_blue[clear]) > 0.995
    assert 0.2 < res.on_blue.mean() < 0.8
    assert res.through == "red"  # the red pipe runs on past the branch


def test_a_stub_end_plate_does_not_pull_the_tee():
    """The through pipe ends in a closed stub 2 radii past I, its end plate textured like the walls: a
    fifth of the points lie on neither cylinder. Left in the cylinder term they tilt the branch by about
    half a degree and move I by 2 mm; the wall rule leaves them out."""
    sc = make_tee_scene(cap_at=0.4, n_cap=600)
    assert sc.on_cap.sum() > 0.15 * len(sc.points)
    res = solve(sc)
    assert res.model.angle_deg == pytest.approx(90.0, abs=0.1)
    assert np.linalg.norm(res.intersection - sc.I) < 0.0012
    # Only the plate's rim, within the Huber threshold of the red wall, stays in.
    assert res.on_wall[sc.on_cap].mean() < 0.5
    assert res.on_wall[~sc.on_cap].mean() > 0.99
    assert res.cylinder_rms_m < 0.001


def test_without_the_cylinders_the_scale_is_not_recovered():
    """Only P_r held and only P_b attached: nothing metric but the cylinders. Started 10 % too large,
    tau = 0 leaves I and P_b where the wrong scale put them; the cylinder terms bring them back."""
    sc = make_tee_scene(n_points=1200, n_red=1, n_blue=1, scale0=1.1, blue_shift=0.0, blue_turn_deg=0.0, seed=3)
    sc.t0[sc.blue_pose] = sc.t[sc.red_pose] + 1.1 * (sc.t[sc.blue_pose] - sc.t[sc.red_pose])
    opts = dict(fixed=(), attached=())
    with_cyl = solve(sc, **opts)
    without = solve(sc, tau=0.0, **opts)
    err_with = np.linalg.norm(with_cyl.intersection - sc.I)
    err_without = np.linalg.norm(without.intersection - sc.I)
    assert err_with < 0.005
    assert err_without > 0.01
    travel = np.linalg.norm(sc.t[sc.blue_pose] - sc.t[sc.red_pose])
    got = np.linalg.norm(without.poses[sc.blue_pose, :3, 3] - sc.t[sc.red_pose])
    assert got / travel > 1.05  # still the wrong scale
    assert without.rms_px < 0.6  # ... though the images are explained just as well


def test_fit_end_cylinders_fits_both_ends_relative_to_the_end_poses():
    rng = np.random.default_rng(4)
    n = 60
    z = np.linspace(0, 2.5, n)
    R = np.repeat(G[None] @ look_rotation(np.array([0, 0, 1.0]), np.array([0, -1.0, 0]))[None], n, axis=0)
    t = np.c_[0.02 * np.sin(z * 5), -0.05 + 0 * z, z] @ G.T + g
    a, zz = rng.uniform(-np.pi, np.pi, 4000), rng.uniform(-0.3, 2.8, 4000)
    X = np.c_[RADIUS * np.cos(a), RADIUS * np.sin(a), zz] @ G.T + g + rng.normal(0, 0.001, (4000, 3))
    first, last = fit_end_cylinders((R, t), X, RADIUS, length_m=1.0)
    axis = G @ np.array([0, 0, 1.0])
    for fit, ref in ((first, 0), (last, n - 1)):
        assert np.allclose(fit.reference[1], t[ref])
        assert np.degrees(np.arccos(abs(fit.cylinder.direction @ axis))) < 0.2
        assert np.linalg.norm(np.cross(fit.cylinder.origin - g, axis)) < 0.001
        # The parameters place the axis relative to the end camera: 5 cm above it, 2 sin(5 z) cm to the side.
        Cyl = Cylinder.from_local(fit.params, *fit.reference, RADIUS)
        assert np.linalg.norm(np.cross(Cyl.origin - g, axis)) < 0.001
    with pytest.raises(PipemapError, match="points"):
        fit_end_cylinder((R, t), X[:3], RADIUS)
    with pytest.raises(PipemapError, match="length"):
        fit_end_cylinder((R, t), X, RADIUS, length_m=0.0)


def _check_gradient(prob: JunctionProblem, points, global_rel: float = 1e-5, global_abs: float = 1e-6):
    """The Schur step of the analytic normal equations equals a Gauss-Newton step from numerical Jacobians,
    checked through the gradient g = J^T W r: without Huber down-weighting the cost is 0.5 |r|^2 x 2, whose
    central differences are 2 g (the global block, every free camera, the `points` listed)."""
    state = prob.initial
    inl = np.ones(len(prob.obs), bool)
    on_blue = prob.assign(state)
    on_wall = np.ones(prob.M, bool)
    eq = prob.normal_equations(state, _Stage(prob, inl), on_blue, on_wall)
    C, G, eps = prob.n_free, prob.n_global, 1e-6

    def slope(dc, dx, dp):
        return (prob.cost(prob._step(state, (dc, dx, dp)), inl, on_blue, on_wall)
                - prob.cost(prob._step(state, (-dc, -dx, -dp)), inl, on_blue, on_wall)) / (2 * eps)

    zc, zx, zp = np.zeros((C, 6)), np.zeros(G), np.zeros((prob.M, 3))
    for k in range(G):
        dx = zx.copy()
        dx[k] = eps
        assert slope(zc, dx, zp) == pytest.approx(2 * eq.gx[k], rel=global_rel, abs=global_abs)
    for c in range(C):
        for k in range(6):
            dc = zc.copy()
            dc[c, k] = eps
            assert slope(dc, zx, zp) == pytest.approx(2 * eq.gc[c, k], rel=1e-5, abs=1e-6)
    for m in points:
        for k in range(3):
            dp = zp.copy()
            dp[m, k] = eps
            assert slope(zc, zx, dp) == pytest.approx(2 * eq.gp[m, k], rel=1e-5, abs=1e-6)


def test_junction_jacobians_match_numerical():
    sc = make_tee_scene(n_points=150, n_red=2, n_tee=6, n_blue=2, outlier_frac=0.0, seed=5)
    prob = JunctionProblem(sc.camera, (sc.R0, sc.t0), sc.points0, sc.obs, sc.red_fit, sc.blue_fit,
                           red_pose=sc.red_pose, blue_pose=sc.blue_pose, fixed=sc.fixed, attached=sc.attached,
                           huber_px=1e6, huber_m=1e6)
    _check_gradient(prob, range(0, prob.M, 17))


@pytest.mark.parametrize("free_red_axis", [False, True])
def test_elbow_jacobians_match_numerical(free_red_axis):
    """An elbow's solve: the points near I on the bend's torus (bend radius rho a sixth global unknown, its
    derivatives by central differences inside the problem, hence the looser global tolerance), the others on
    their cylinders; with the red axis free, its four parameters join the global block."""
    sc = make_tee_scene(n_points=150, n_red=2, n_tee=6, n_blue=2, outlier_frac=0.0, seed=6)
    bend = np.linalg.norm(sc.points0 - sc.I, axis=1) < 0.35
    prob = JunctionProblem(sc.camera, (sc.R0, sc.t0), sc.points0, sc.obs, sc.red_fit, sc.blue_fit,
                           red_pose=sc.red_pose, blue_pose=sc.blue_pose, fixed=sc.fixed, attached=sc.attached,
                           huber_px=1e6, huber_m=1e6, cylinder_points=~bend, torus_points=bend, bend_radius=0.3,
                           free_red_axis=free_red_axis, through=None)
    assert prob.n_global == (10 if free_red_axis else 6) and bend.sum() > 10
    _check_gradient(prob, np.r_[np.flatnonzero(bend)[:8], np.flatnonzero(~bend)[::29]], 1e-4, 1e-5)


def test_bad_input_is_reported(scene):
    sc = scene
    with pytest.raises(ValueError, match="both"):
        JunctionProblem(sc.camera, (sc.R0, sc.t0), sc.points0, sc.obs, sc.red_fit, sc.blue_fit,
                        red_pose=sc.red_pose, blue_pose=sc.blue_pose, fixed=[sc.blue_pose])
    with pytest.raises(PipemapError, match="radius"):
        JunctionProblem(sc.camera, (sc.R0, sc.t0), sc.points0, sc.obs, sc.red_fit.params, sc.blue_fit.params,
                        red_pose=sc.red_pose, blue_pose=sc.blue_pose)


def test_a_held_angle_stays_and_the_rest_is_solved(scene, solved):
    """A tee is a fitting whose pipes meet at 90 deg: held there, from the free solve, the solve keeps it
    exactly and places I and the poses as well as the free one did; held 1.5 deg off, the blue side turns with it.
    The images hardly object (the tee span's free cameras take the turn up: RMS 0.634 -> 0.636 px), the walls do."""
    sc, free = scene, solved
    R0, t0 = as_rt(free.poses)
    def held(deg):
        model = free.model.params.copy()
        return solve_junction(sc.camera, (R0, t0), free.points, sc.obs, sc.red_fit, sc.blue_fit, red_pose=sc.red_pose,
                              blue_pose=sc.blue_pose, fixed=sc.fixed, attached=sc.attached, settings=Settings(),
                              model=model, angle=np.radians(deg))
    right, wrong = held(90.0), held(91.5)
    assert right.model.angle_deg == pytest.approx(90.0, abs=1e-9)
    assert right.converged
    assert np.linalg.norm(right.intersection - sc.I) < 0.001
    pos, rot = pose_errors(right, sc)
    assert pos.max() < 0.0015 and rot.max() < 0.25
    assert right.rms_px == pytest.approx(free.rms_px, rel=0.01)
    assert wrong.model.angle_deg == pytest.approx(91.5, abs=1e-9)
    pos, rot = pose_errors(wrong, sc)
    assert rot[sc.attached].min() > 1.0  # the blue section follows the held angle
    assert wrong.cylinder_rms_m > 1.3 * free.cylinder_rms_m


def test_a_held_angle_must_be_an_angle_between_axes(scene):
    sc = scene
    with pytest.raises(ValueError, match="held angle"):
        JunctionProblem(sc.camera, (sc.R0, sc.t0), sc.points0, sc.obs, sc.red_fit, sc.blue_fit,
                        red_pose=sc.red_pose, blue_pose=sc.blue_pose, angle=np.pi)
