"""Bundle adjustment with the cylinder prior on a synthetic straight pipe seen by a 190 deg fisheye.

The scene: a pipe of radius 0.2 m, a camera crawling ~1 cm per keyframe along it, off-centre and
wobbling, wall points tracked over 3-7 keyframes, 0.5 px pixel noise and 5 % gross outliers (5-40 px
off). The solver starts from poses and points at 0.9 x the true scale, perturbed.
"""

from __future__ import annotations


import numpy as np
import pytest

from pipemap.backend import BundleProblem, Observations
from pipe_window import RADIUS, PipeWindow, make_pipe_window
from pipemap.solvers.schur import SchurStructure, block_sum, observation_pairs, solve_damped
from pipemap.geometry.cylinder import Cylinder, fit_cylinder
from pipemap.geometry.rotations import log_so3

def observations_of(w: PipeWindow) -> Observations:
    return Observations(w.obs_camera, w.obs_point, w.obs_pixels)


@pytest.fixture(scope="module")
def window() -> PipeWindow:
    return make_pipe_window()


def small_problem(seed=1, tau=2.5e5, fixed_poses=(), bend_knot_m=None):
    """A few keyframes at a perturbed state, for derivative checks; with a bend, its offsets are
    set to a few millimetres."""
    w = make_pipe_window(n_frames=8, n_points=60, outlier_frac=0.0, seed=seed)
    cyl = Cylinder(w.cylinder.origin + 0.01, w.cylinder.direction + 0.02, RADIUS)
    prob = BundleProblem(w.camera, (w.R0, w.t0), w.points0, observations_of(w), cylinder=cyl, tau=tau,
                         fixed_poses=fixed_poses, bend_knot_m=bend_knot_m)
    if bend_knot_m is not None:
        prob.initial.cylinder[4:] = np.random.default_rng(seed).normal(0, 0.003, len(prob.initial.cylinder) - 4)
    return w, prob


@pytest.mark.parametrize("bend_knot_m", [None, 0.02])
def test_reprojection_and_cylinder_jacobians_match_numerical_ones(bend_knot_m):
    w, prob = small_problem(bend_knot_m=bend_knot_m)
    s = prob.initial
    if bend_knot_m is not None:
        assert len(prob.knots) >= 4
    lin = prob.linearise(s)
    N, M, eps = len(s.R), len(s.points), 1e-6
    cam, pt = prob.obs.camera, prob.obs.point
    # Pose blocks: perturb each pose along each of its 6 directions.
    for i in range(6):
        d = np.zeros((N, 6))
        d[:, i] = eps
        plus = prob.linearise(s.retract(d, 0.0), jacobians=False)
        minus = prob.linearise(s.retract(-d, 0.0), jacobians=False)
        num = (plus.reproj - minus.reproj) / (2 * eps)
        scale = np.abs(lin.J_pose[:, :, i]).max()
        assert np.abs(num - lin.J_pose[:, :, i]).max() < 1e-6 * scale  # relative to the largest entry
    for i in range(3):
        d = np.zeros((M, 3))
        d[:, i] = eps
        plus = prob.linearise(s.retract(np.zeros((N, 6)), d), jacobians=False)
        minus = prob.linearise(s.retract(np.zeros((N, 6)), -d), jacobians=False)
        num = (plus.reproj - minus.reproj) / (2 * eps)
        assert np.abs(num - lin.J_point[:, :, i]).max() < 1e-6 * np.abs(lin.J_point[:, :, i]).max()
        num_d = (plus.dist - minus.dist) / (2 * eps)
        assert np.abs(num_d - lin.Jd_point[:, i]).max() < 1e-7
    q = len(s.cylinder)
    for i in range(q):
        d = np.zeros(q)
        d[i] = eps
        zero = (np.zeros((N, 6)), np.zeros((M, 3)))
        num_d = (prob.linearise(s.retract(*zero, d), False).dist
                 - prob.linearise(s.retract(*zero, -d), False).dist) / (2 * eps)
        assert np.abs(num_d - lin.Jd_cyl[:, i]).max() < 1e-7
    assert len(np.unique(cam)) == N and len(np.unique(pt)) == M


@pytest.mark.parametrize("bend_knot_m", [None, 0.02])
def test_schur_step_equals_the_dense_damped_normal_equations(bend_knot_m):
    w, prob = small_problem(seed=2, fixed_poses=(0,), bend_knot_m=bend_knot_m)
    inl = np.ones(len(prob.obs), bool)
    inl[::7] = False
    eq = prob.normal_equations(prob.initial, inl)
    C, M, q = len(eq.U), len(eq.V), len(eq.gx)
    n = 6 * C + q + 3 * M
    H, g = np.zeros((n, n)), np.zeros(n)
    for c in range(C):
        H[6 * c:6 * c + 6, 6 * c:6 * c + 6] += eq.U[c]
        g[6 * c:6 * c + 6] = eq.gc[c]
    H[6 * C:6 * C + q, 6 * C:6 * C + q] = eq.Ux
    g[6 * C:6 * C + q] = eq.gx
    p0 = 6 * C + q
    Wx = eq.global_point_coupling()
    for m in range(M):
        H[p0 + 3 * m:p0 + 3 * m + 3, p0 + 3 * m:p0 + 3 * m + 3] = eq.V[m]
        g[p0 + 3 * m:p0 + 3 * m + 3] = eq.gp[m]
        H[6 * C:6 * C + q, p0 + 3 * m:p0 + 3 * m + 3] = Wx[m]
    for k in range(len(eq.obs_cam)):
        c, m = eq.obs_cam[k], eq.obs_pt[k]
        H[6 * c:6 * c + 6, p0 + 3 * m:p0 + 3 * m + 3] += eq.W[k]
    H = np.triu(H) + np.triu(H, 1).T
    lam = 1e-2
    D = H + lam * np.diag(np.diag(H))
    D[p0:, p0:] += 1e-12 * (np.einsum("mii->mi", eq.V).max() + 1) * np.eye(3 * M)
    dense = np.linalg.solve(D, -g)
    dc, dx, dp = solve_damped(eq, SchurStructure(eq.obs_cam, eq.obs_pt, C, M), lam)
    got = np.concatenate([dc.ravel(), dx, dp.ravel()])
    assert np.abs(got - dense).max() < 1e-8 * np.abs(dense).max()


def test_sparse_block_sums_equal_bincount_sums():
    rng = np.random.default_rng(3)
    idx = rng.integers(0, 7, 200)
    blocks = rng.normal(size=(200, 6, 3))
    st = SchurStructure(idx, rng.integers(0, 30, 200), 7, 30)
    assert np.allclose(st.to_cam(blocks), block_sum(idx, blocks, 7), atol=1e-12)
    loop = np.zeros((7, 6, 3))
    np.add.at(loop, idx, blocks)
    assert np.allclose(loop, block_sum(idx, blocks, 7), atol=1e-12)


def test_camera_rows_times_a_matrix_equal_the_cameras_sums_of_outer_products_exactly():
    rng = np.random.default_rng(5)
    seen = rng.permutation(9 * 40)[:300]  # each camera sees a point at most once
    cams, pts = seen // 40, seen % 40
    cams[cams == 4] = 5  # a camera that sees nothing
    st = SchurStructure(cams, pts, 9, 40)
    rows, right = rng.normal(size=(300, 6)), rng.normal(size=(40, 11))
    want = st.to_cam(rows[:, :, None] * right[pts][:, None, :]).reshape(54, 11)
    assert np.array_equal(st.cam_rows(rows) @ right, want)  # the same products summed in the same order
    assert not np.any(want[24:30])
    empty = SchurStructure(np.zeros(0, int), np.zeros(0, int), 2, 0)
    assert (empty.cam_rows(np.zeros((0, 6))) @ np.zeros((0, 3))).shape == (12, 3)


def test_sums_taken_a_run_of_bins_at_a_time_equal_the_whole_sums_exactly():
    from pipemap.solvers.schur import BlockSummer, RunSummer

    rng = np.random.default_rng(8)
    key = rng.integers(0, 50, 1000)
    key[key == 7] = 8  # an empty bin
    key[:40] = 3  # a bin with more items than a run holds
    left, right = rng.normal(size=(1000, 6, 3)), rng.normal(size=(1000, 3, 6))
    want = BlockSummer(key, 50)(left @ right)
    for budget in (1, 16, 37, 5000):
        runs = RunSummer(key, 50, max_items=budget)
        assert np.array_equal(runs(lambda i: left[i] @ right[i], (6, 6)), want)
    assert not np.any(want[7])
    assert RunSummer(np.zeros(0, int), 4)(lambda i: left[i] @ right[i], (6, 6)).shape == (4, 6, 6)


def test_observation_pairs_lists_each_pair_of_the_same_point_once():
    pt = np.array([3, 1, 3, 0, 1, 3, 2])
    a, b = observation_pairs(pt)
    got = sorted(tuple(sorted(p)) for p in zip(a.tolist(), b.tolist()))
    want = sorted((i, j) for i in range(len(pt)) for j in range(i + 1, len(pt)) if pt[i] == pt[j])
    assert got == want


@pytest.fixture(scope="module")
def solved(window):
    fit = fit_cylinder(window.points0, RADIUS, reference=(window.R0[0], window.t0[0]))
    # Huber at twice the window's 0.5 px noise: the scale comes back from 10 % off within the 20 iterations
    start = (window.camera, (window.R0, window.t0), window.points0, observations_of(window))
    with_cyl = BundleProblem(*start, cylinder=fit, huber_px=1.0).solve()
    no_cyl = BundleProblem(*start, tau=0.0, huber_px=1.0).solve()
    return fit, with_cyl, no_cyl


def path_length(t):
    return np.linalg.norm(np.diff(t, axis=0), axis=1).sum()


def test_the_cylinder_prior_recovers_the_metric_trajectory_from_the_wrong_scale(window, solved):
    _, res, _ = solved
    t_est = res.poses[:, :3, 3]
    true_len = path_length(window.t)
    start = np.linalg.norm(window.t0[-1] - window.t0[0]) / np.linalg.norm(window.t[-1] - window.t[0])
    assert abs(start - 0.9) < 0.01  # it did start at the wrong scale
    assert abs(path_length(t_est) / true_len - 1) < 0.001  # distance travelled within 0.1 %
    end = np.linalg.norm(t_est[-1] - t_est[0]) / np.linalg.norm(window.t[-1] - window.t[0])
    assert abs(end - 1) < 0.001
    rmse = np.sqrt(np.mean(np.sum((t_est - window.t) ** 2, axis=1)))
    assert rmse < 0.001  # m, no alignment: the first pose is the gauge
    rot_err = np.degrees(np.linalg.norm(log_so3(np.swapaxes(res.poses[:, :3, :3], 1, 2) @ window.R), axis=1))
    # Tracks of 3-7 keyframes tie rotations only loosely: the optimum itself (also when started at the
    # truth) drifts ~0.3 deg over 80 keyframes at 0.5 px noise; 10-20 keyframe tracks give ~0.1 deg.
    assert rot_err.max() < 0.5  # deg
    assert np.array_equal(res.poses[0], np.vstack([np.column_stack([window.R[0], window.t[0]]), [0, 0, 0, 1]]))
    pts = res.point_inliers
    assert np.sqrt(np.mean(np.sum((res.points[pts] - window.points[pts]) ** 2, 1))) < 0.002
    ang = np.degrees(np.arccos(min(1.0, abs(res.cylinder.direction @ window.cylinder.direction))))
    assert ang < 0.1
    assert np.linalg.norm(np.cross(res.cylinder.origin - window.cylinder.origin, window.cylinder.direction)) < 0.001
    assert res.rms_px < 0.7 and res.cylinder_rms_m < 0.002 and res.converged


def test_without_the_cylinder_the_scale_stays_wrong(window, solved):
    _, with_cyl, no_cyl = solved
    true_len = path_length(window.t)
    err_free = abs(path_length(no_cyl.poses[:, :3, 3]) / true_len - 1)
    err_cyl = abs(path_length(with_cyl.poses[:, :3, 3]) / true_len - 1)
    assert err_free > 0.05 and err_free > 50 * err_cyl
    assert no_cyl.rms_px < 0.7  # the images are explained just as well: scale is unobservable from them


def test_gross_outliers_are_flagged(window, solved):
    for res in solved[1:]:
        flagged = ~res.inliers
        assert flagged[window.outlier].mean() > 0.9  # recall
        assert flagged[~window.outlier].mean() < 0.02  # few good observations lost
        assert len(res.outlier_counts) >= 1


def test_tau_zero_gauges_hold_the_scale_they_are_given(window):
    kw = dict(tau=0.0, max_iterations=6, outlier_passes=1)
    d0 = np.linalg.norm(window.t0[-1] - window.t0[0])
    res = BundleProblem(window.camera, (window.R0, window.t0), window.points0, observations_of(window),
                        fixed_distance=(0, len(window.t0) - 1), **kw).solve()
    assert abs(np.linalg.norm(res.poses[-1, :3, 3] - res.poses[0, :3, 3]) - d0) < 1e-5  # m
    res = BundleProblem(window.camera, (window.R0, window.t0), window.points0, observations_of(window),
                        fixed_poses=(0, 5), **kw).solve()
    assert (np.allclose(res.poses[5, :3, 3], window.t0[5], atol=0)
            and np.allclose(res.poses[5, :3, :3], window.R0[5], atol=0))


def test_solving_is_deterministic(window):
    kw = dict(max_iterations=4, outlier_passes=1, cylinder=window.cylinder)
    a = BundleProblem(window.camera, (window.R0, window.t0), window.points0, observations_of(window), **kw).solve()
    b = BundleProblem(window.camera, (window.R0, window.t0), window.points0, observations_of(window), **kw).solve()
    assert np.array_equal(a.poses, b.poses) and np.array_equal(a.points, b.points)
    assert np.array_equal(a.inliers, b.inliers) and a.cost_history == b.cost_history


def test_settings_supply_the_papers_values(window):
    from pipemap.config import Settings

    s = Settings()
    prob = BundleProblem.from_settings(window.camera, (window.R0, window.t0), window.points0, observations_of(window),
                                       s, cylinder=window.cylinder, max_iterations=3)
    assert prob.tau == 2.5e5 and prob.huber_px == s.bundle.huber_px and prob.mad_k == s.bundle.mad_k
    assert prob.max_iterations == 3
    res = prob.solve()
    assert res.iterations <= 3 and res.poses.shape == (len(window.R0), 4, 4)


def test_bad_observation_indices_are_refused(window):
    obs = Observations(observations_of(window).camera, observations_of(window).point.copy(),
                       observations_of(window).pixels)
    obs.point[0] = len(window.points0)
    with pytest.raises(ValueError, match="out of range"):
        BundleProblem(window.camera, (window.R0, window.t0), window.points0, obs)
    with pytest.raises(ValueError, match="disagree"):
        Observations([0, 1], [0], np.zeros((2, 2)))


def test_a_single_free_pose_solves(window):
    """A window whose poses are all held but one: no pair of free cameras shares a point."""
    n = len(window.R0)
    res = BundleProblem(window.camera, (window.R0, window.t0), window.points0, observations_of(window),
                        cylinder=fit_cylinder(window.points0, RADIUS, reference=(window.R0[0], window.t0[0])),
                        fixed_poses=tuple(range(n - 1))).solve()
    assert np.isfinite(res.poses).all() and res.iterations >= 1


def _sag_window_errors(sag_m: float, knot_m: float | None, offset_mm: float = 2.0) -> tuple[float, float]:
    """Median point error (m, after aligning the cameras rigidly) and length error of a 1.5 m window."""
    from pipemap.evaluation.align import umeyama

    w = make_pipe_window(n_frames=150, n_points=4000, sag_m=sag_m, seed=3, outlier_frac=0.02)
    fit = fit_cylinder(w.points0, RADIUS, reference=(w.R0[0], w.t0[0]), direction=w.t0[-1] - w.t0[0])
    res = BundleProblem(w.camera, (w.R0, w.t0), w.points0, observations_of(w), cylinder=fit, huber_px=0.5,
                        bend_knot_m=knot_m, bend_offset_mm=offset_mm).solve()
    c = res.poses[:, :3, 3]
    R, t, _ = umeyama(c, w.t)
    points = np.linalg.norm(res.points @ R.T + t - w.points, axis=1)[res.point_inliers]
    length = np.linalg.norm(c[-1] - c[0]) / np.linalg.norm(w.t[-1] - w.t[0]) - 1
    return float(np.median(points)), float(length)


def test_a_bent_axis_follows_a_sagging_pipe_that_a_straight_one_straightens():
    """Two pieces meeting 3 mm low half-way along a 1.5 m window (a 0.46 deg kink): the straight
    cylinder bends the points and shortens the window (measured: median point error 1.55 mm,
    length -0.087 %). With knots every 0.25 m and the offsets held loosely (10 mm) the axis
    follows the sag: 1.06 mm, -0.047 %; held to 2 mm, as window solves hold them against heading
    drift, part way: 1.23 mm, -0.078 %. In a straight pipe the bend costs nothing (1.01 vs 1.06 mm)."""
    straight, straight_len = _sag_window_errors(0.003, None)
    loose, loose_len = _sag_window_errors(0.003, 0.25, offset_mm=10.0)
    held, held_len = _sag_window_errors(0.003, 0.25)
    assert loose < 0.75 * straight and abs(loose_len) < 0.7 * abs(straight_len)
    assert held < 0.85 * straight and abs(held_len) < abs(straight_len)
    plain, _ = _sag_window_errors(0.0, None)
    plain_bent, _ = _sag_window_errors(0.0, 0.25)
    assert plain_bent < 1.05 * plain


def test_an_axis_prior_holds_the_cylinders_direction():
    """A tight prior on the axis direction keeps the solved axis at it (to 0.003 deg) where the free axis of the
    same few keyframes lands elsewhere; the prior's direction counts, not its sign."""
    w, free = small_problem(seed=3, fixed_poses=(0,))
    target = w.cylinder.direction + np.array([0.0, 0.01, 0.0])
    target /= np.linalg.norm(target)
    held = BundleProblem(w.camera, (w.R0, w.t0), w.points0, observations_of(w), cylinder=Cylinder(
        w.cylinder.origin + 0.01, w.cylinder.direction + 0.02, RADIUS), fixed_poses=(0,),
        axis_prior=(-target, np.radians(0.001)))

    def off_deg(res):
        return np.degrees(np.arccos(min(1.0, abs(res.cylinder.direction @ target))))

    assert off_deg(held.solve()) < 0.003  # the prior's sigma is 0.001 deg
    assert off_deg(free.solve()) > 1.0  # measured 2.7 deg


def test_observation_sigmas_weigh_the_normal_equations_as_the_cost():
    """With a sigma per observation the gradient of the normal equations is half the cost's numerical gradient
    (the reprojection terms divided by sigma, Huber on the divided residual), in both Huber regions."""
    w = make_pipe_window(n_frames=8, n_points=60, outlier_frac=0.0, seed=3)
    sigma = np.random.default_rng(3).uniform(0.3, 3.0, len(w.obs_pixels))
    prob = BundleProblem(w.camera, (w.R0, w.t0), w.points0, observations_of(w), tau=0.0, fixed_poses=(0,),
                         huber_px=0.5, observation_sigma=sigma)
    s, inl = prob.initial, np.ones(len(prob.obs), bool)
    a = np.linalg.norm(prob.linearise(s, False).reproj, axis=1) / sigma
    assert (a < 0.5).any() and (a > 0.5).any()  # both sides of the Huber threshold
    eq = prob.normal_equations(s, inl)
    N, M, eps = len(s.R), len(s.points), 1e-6

    def slope(dc, dp):  # the cost's central difference along (pose, point) perturbation directions
        return (prob.cost(s.retract(dc, dp), inl) - prob.cost(s.retract(-dc, -dp), inl)) / (2 * eps)

    for i in (0, 4):
        d = np.zeros((N, 6))
        d[3, i] = eps
        assert slope(d, np.zeros((M, 3))) == pytest.approx(2 * eq.gc[prob.free_index[3], i], rel=1e-5)
    for m in (0, 7):
        d = np.zeros((M, 3))
        d[m, 1] = eps
        assert slope(np.zeros((N, 6)), d) == pytest.approx(2 * eq.gp[m, 1], rel=1e-5)
    with pytest.raises(ValueError, match="observation_sigma"):
        BundleProblem(w.camera, (w.R0, w.t0), w.points0, observations_of(w), observation_sigma=sigma[:-1])


def test_sigmas_that_know_the_noisy_observations_give_a_better_trajectory():
    """Half the observations 40x noisier than the rest (as a track's late anchor matches are a few times noisier
    than its early ones): weighted by their sigmas the poses come out closer to the truth than weighted alike."""
    w = make_pipe_window(n_frames=30, n_points=900, noise_px=0.05, outlier_frac=0.0, scale0=1.0, seed=4)
    rng = np.random.default_rng(5)
    noisy = rng.random(len(w.obs_pixels)) < 0.5
    pixels = w.obs_pixels + noisy[:, None] * rng.normal(0.0, 2.0, w.obs_pixels.shape)
    obs = Observations(w.obs_camera, w.obs_point, pixels)
    kw = dict(cylinder=w.cylinder, huber_px=4.0, max_iterations=10, outlier_passes=0)
    errors = []
    for sigma in (None, np.where(noisy, 40.0, 1.0)):
        res = BundleProblem(w.camera, (w.R0, w.t0), w.points0, obs, observation_sigma=sigma, **kw).solve()
        errors.append(np.sqrt(np.mean(np.sum((res.poses[:, :3, 3] - w.t) ** 2, axis=1))))
    alike, weighted = errors  # measured 1.45 and 0.083 mm
    assert weighted < 0.2 * alike
    assert weighted < 1.5e-4  # m: what the quiet half's 0.05 px allow
