"""Checkerboard calibration: recovery of every model from seeded synthetic corners, OpenCV as a peer for
the pinhole model, the analytic Jacobian against a numerical one, and rendered images end to end."""

import cv2
import numpy as np
import pytest
import yaml
from scipy.optimize._numdiff import approx_derivative

from pipemap.camera import KannalaBrandtCamera, PinholeCamera, PolynomialCamera, load_camera
from pipemap.camera.calibration import (CalibrationProblem, board_points, calibrate_from_corners, calibrate_images,
                                        detect_corners, pose_from_bearings, save_calibration)
from pipemap.errors import PipemapError
from pipemap.geometry.rotations import exp_so3
from pipemap.sim.board import random_board_poses, render_board_views, save_board_views

BOARD, SQUARE = (9, 6), 0.025


def fisheye_190(k3=0.8, k4=-0.15):
    return PolynomialCamera(1280, 960, dict(k1=290.0, k2=-2.5, k3=k3, k4=k4, u0=641.2, v0=478.3), 95)


def kb():
    return KannalaBrandtCamera(1280, 960, dict(fx=300.0, fy=302.0, cx=640.4, cy=481.1,
                                               k1=0.02, k2=-0.01, k3=0.003, k4=-0.0005), 95)


def pinhole():
    return PinholeCamera(1024, 768, dict(fx=730.0, fy=731.5, cx=512.3, cy=383.2,
                                         k1=-0.28, k2=0.09, p1=0.001, p2=-0.0007, k3=-0.01))


def synthetic_corners(cam, n_views=18, seed=0, noise_px=0.3):
    """Board corners projected under random seeded poses, with Gaussian pixel noise; and their colatitudes."""
    rng = np.random.default_rng(seed)
    obj = board_points(BOARD, SQUARE)
    views, thetas = [], []
    for rvec, tvec in random_board_poses(cam, BOARD, SQUARE, n_views, rng):
        X = obj @ exp_so3(rvec).T + tvec
        uv, valid = cam.project(X)
        assert valid.all()
        views.append(uv + rng.normal(0.0, noise_px, uv.shape))
        thetas.append(np.degrees(cam.colatitude(X)).max())
    return views, np.array(thetas)


def calibrate(cam, views, **kw):
    return calibrate_from_corners(views, BOARD, SQUARE, cam.model, cam.width, cam.height,
                                  max_theta_deg=None if cam.model == "pinhole" else 95, **kw)


def test_polynomial_fisheye_190_acceptance():
    cam = fisheye_190()
    views, thetas = synthetic_corners(cam, n_views=18)
    assert thetas.max() > 80  # the periphery, where k2..k4 show, is covered
    res = calibrate(cam, views)
    k1_err = abs(res.camera.params[0] / cam.params[0] - 1)
    # 0.3 px per coordinate is 0.42 px per corner: the fit should sit at the noise floor.
    assert res.rms_px < 0.5
    assert k1_err < 0.005
    assert np.allclose(res.camera.params[4:], cam.params[4:], atol=1.0)
    assert res.dropped == [] and len(res.per_view_rms) == len(views) == len(res.poses)
    assert res.camera.max_theta_deg == pytest.approx(95)
    # The recovered radius function, not just k1, matches over the whole field of view.
    theta = np.radians(np.linspace(1, 90, 50))
    assert np.abs(res.camera._radius(theta)[0] - cam._radius(theta)[0]).max() < 1.0


def test_kannala_brandt_recovery():
    cam = kb()
    views, _ = synthetic_corners(cam, n_views=18, seed=1)
    res = calibrate(cam, views)
    assert res.rms_px < 0.5
    assert np.allclose(res.camera.params[:2], cam.params[:2], rtol=0.005)
    assert np.allclose(res.camera.params[2:4], cam.params[2:4], atol=1.0)


def test_pinhole_agrees_with_opencv():
    cam = pinhole()
    views, _ = synthetic_corners(cam, n_views=18, seed=0)
    res = calibrate(cam, views)
    obj = board_points(BOARD, SQUARE).astype(np.float32)
    rms, K, dist, _, _ = cv2.calibrateCamera([obj] * len(views), [v.astype(np.float32) for v in views],
                                             (cam.width, cam.height), None, None)
    ours = res.camera.params
    assert res.rms_px < 0.5
    assert np.allclose(ours[:2], cam.params[:2], rtol=0.01)
    # Same model, same cost: both optimisers should land on the same minimum.
    assert res.rms_px == pytest.approx(rms, abs=1e-4)
    assert np.allclose(ours[:4], K[[0, 1, 0, 1], [0, 1, 2, 2]], atol=0.02)
    assert np.allclose(ours[4:], dist.ravel()[:5], atol=1e-4)


@pytest.mark.parametrize("make", [fisheye_190, kb, pinhole])
def test_analytic_jacobian_matches_numerical(make):
    cam = make()
    views, _ = synthetic_corners(cam, n_views=3, seed=3)
    obj = board_points(BOARD, SQUARE)
    poses = np.array([np.concatenate(pose_from_bearings(obj, cam.unproject(v)[0])) for v in views])
    poses[:, :3] += 0.05  # away from any special point of the rotation vector
    free = np.ones(len(cam.params), bool)
    free[2] = False
    prob = CalibrationProblem(cam, obj, np.stack(views), free)
    x = prob.pack(cam.params, poses[:, :3], poses[:, 3:])
    J = prob.jacobian(x).toarray()
    J_num = approx_derivative(prob.residuals, x, method="3-point")
    scale = np.abs(J_num).max(axis=0) + 1e-9
    assert np.all(np.abs(J - J_num).max(axis=0) / scale < 1e-5)


def test_pose_from_bearings_past_90_degrees():
    obj = board_points(BOARD, SQUARE)
    R = exp_so3(np.array([0.2, 1.5, 0.1]))
    t = np.array([0.12, -0.06, 0.1])
    X = obj @ R.T + t
    theta = np.degrees(np.arctan2(np.hypot(X[:, 0], X[:, 1]), X[:, 2]))
    assert theta.max() > 95 and theta.min() < 90  # the board straddles the image plane
    rvec, tvec = pose_from_bearings(obj, X / np.linalg.norm(X, axis=1, keepdims=True))
    assert np.allclose(exp_so3(rvec), R, atol=1e-9) and np.allclose(tvec, t, atol=1e-9)


def test_fixed_parameters_stay_put():
    cam = fisheye_190(k3=0.0, k4=0.0)
    views, _ = synthetic_corners(cam, n_views=15, seed=4)
    res = calibrate(cam, views, fix=("k3", "k4"))
    assert res.camera.params[2] == 0.0 and res.camera.params[3] == 0.0
    assert abs(res.camera.params[0] / 290.0 - 1) < 0.005
    with pytest.raises(PipemapError, match="cannot fix"):
        calibrate(cam, views, fix=("p1",))


def test_a_wrong_view_is_dropped_and_reported():
    cam = fisheye_190()
    views, _ = synthetic_corners(cam, n_views=15, seed=5)
    bad = np.random.default_rng(0).permutation(views[7])  # corners matched to the wrong board points
    res = calibrate(cam, views[:7] + [bad] + views[7:])
    assert [k for k, _ in res.dropped] == [7]
    assert "px" in res.dropped[0][1]
    assert 7 not in res.used and len(res.used) == 15
    assert res.rms_px < 0.5 and abs(res.camera.params[0] / 290.0 - 1) < 0.005


def test_too_few_views_is_a_pipemap_error():
    cam = fisheye_190()
    views, _ = synthetic_corners(cam, n_views=2, seed=6)
    with pytest.raises(PipemapError, match="at least 3"):
        calibrate(cam, views)
    with pytest.raises(PipemapError, match="unknown camera model"):
        calibrate_from_corners(views * 2, BOARD, SQUARE, "orthographic", 1280, 960)


def test_detected_corners_follow_board_points():
    cam = PolynomialCamera(640, 480, dict(k1=145.0, k2=-1.0, k3=0.4, k4=-0.08, u0=320.6, v0=239.2), 95)
    view = render_board_views(cam, BOARD, SQUARE, n_views=1, seed=7, noise_sigma=0.0)[0]
    corners = detect_corners(view.image, BOARD)
    truth, _ = cam.project(board_points(BOARD, SQUARE) @ exp_so3(view.rvec).T + view.tvec)
    grid = corners.reshape(BOARD[1], BOARD[0], 2)
    # Any symmetry of the grid is the same board under another rigid pose.
    orders = [grid, grid[::-1, ::-1], grid[::-1], grid[:, ::-1]]
    err = min(np.linalg.norm(o.reshape(-1, 2) - truth, axis=1).max() for o in orders)
    assert err < 0.5
    assert detect_corners(np.full((480, 640), 128, np.uint8), BOARD) is None


def test_calibrate_rendered_images_and_skip_bad_ones(tmp_path):
    """End to end: rendered fisheye views -> detected corners -> calibration -> camera file."""
    cam = PolynomialCamera(640, 480, dict(k1=145.0, k2=-1.0, k3=0.4, k4=-0.08, u0=320.6, v0=239.2), 95)
    paths = save_board_views(tmp_path / "board", cam, BOARD, SQUARE, n_views=15, seed=0)
    blank = tmp_path / "board" / "images" / "000100.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    garbage = tmp_path / "board" / "images" / "000101.png"
    garbage.write_text("not an image")
    res = calibrate_images(paths + [blank, garbage], BOARD, SQUARE, "polynomial", max_theta_deg=95)
    reasons = dict(res.skipped)
    assert "board not found" in reasons[blank] and reasons[garbage] == "unreadable image"
    assert len(res.images) >= 13  # at most a couple of extreme views may defeat the detector
    assert res.rms_px < 0.5
    assert abs(res.camera.params[0] / 145.0 - 1) < 0.01
    assert np.allclose(res.camera.params[4:], cam.params[4:], atol=1.0)

    out = tmp_path / "camera.yaml"
    save_calibration(out, res)
    assert np.allclose(load_camera(out).params, res.camera.params)
    doc = yaml.safe_load(out.read_text())["calibration"]
    assert doc["board"] == "9x6" and doc["square_m"] == SQUARE and doc["rms_px"] < 0.5
    assert [v["image"] for v in doc["views"]] == [p.name for p in res.images]
    assert {s["image"] for s in doc["skipped"]} >= {"000100.png", "000101.png"}


def test_too_few_boards_in_images_names_the_input(tmp_path):
    paths = []
    for k in range(4):
        paths.append(tmp_path / f"{k}.png")
        cv2.imwrite(str(paths[-1]), np.full((120, 160), 90 + k, np.uint8))
    with pytest.raises(PipemapError, match=r"cal/\*\.png.*found in 0 of 4 images"):
        calibrate_images(paths, BOARD, SQUARE, "polynomial", source="cal/*.png")


def test_a_misplaced_corner_is_left_out_and_its_view_kept():
    cam = fisheye_190()
    views, _ = synthetic_corners(cam, n_views=12, seed=8)
    views[4] = views[4].copy()
    views[4][17] += (6.0, -4.0)  # e.g. a corner cut by the image circle or lost in glare
    res = calibrate(cam, views)
    assert res.rejected == [(4, 17)] and res.dropped == [] and 4 in res.used
    assert res.rms_px < 0.5 and abs(res.camera.params[0] / cam.params[0] - 1) < 0.005
    assert res.per_view_rms[res.used.index(4)] < 0.6
    assert len(res.corners) == len(res.used) and np.array_equal(res.corners[4], views[4])


def test_masked_corners_drop_out_of_residuals_and_jacobian():
    cam = fisheye_190()
    views, _ = synthetic_corners(cam, n_views=3, seed=9)
    obj = board_points(BOARD, SQUARE)
    poses = np.array([np.concatenate(pose_from_bearings(obj, cam.unproject(v)[0])) for v in views])
    mask = np.ones((3, len(obj)), bool)
    mask[1, [0, 5, 30]] = False
    prob = CalibrationProblem(cam, obj, np.stack(views), np.ones(len(cam.params), bool), mask)
    x = prob.pack(cam.params, poses[:, :3], poses[:, 3:])
    r = prob.residuals(x).reshape(3, len(obj), 2)
    assert np.all(r[~mask] == 0) and np.all(r[mask] != 0)
    J = prob.jacobian(x).toarray()
    J_num = approx_derivative(prob.residuals, x, method="3-point")
    scale = np.abs(J_num).max(axis=0) + 1e-9
    assert np.all(np.abs(J - J_num).max(axis=0) / scale < 1e-5)
    assert prob.rms(x) == pytest.approx(np.sqrt(np.sum(r**2) / mask.sum()))
