"""Corner placement: the point-symmetry fit against the simulator's true corners on sharp, blurred,
overexposed and unevenly lit fisheye renders (the conditions of the real 190 deg views), calibration from
overexposed renders, the local grid and its Jacobian, and corners the fit cannot place."""

import cv2
import numpy as np
import pytest
from scipy.optimize._numdiff import approx_derivative

from pipemap.camera import PolynomialCamera
from pipemap.camera.calibration import board_points, calibrate_from_corners
from pipemap.camera.corners import detect_corners, grid_map, local_grids, refine_corners
from pipemap.geometry.rotations import exp_so3
from pipemap.sim.board import render_board_views

BOARD, SQUARE = (9, 6), 0.025


def fisheye():
    return PolynomialCamera(640, 480, dict(k1=145.0, k2=-1.0, k3=0.4, k4=-0.08, u0=320.6, v0=239.2), 95)


def blurred(image, sigma=1.5):
    return np.clip(cv2.GaussianBlur(image.astype(np.float32), (0, 0), sigma), 0, 255).astype(np.uint8)


def overexposed(image, sigma=1.5, gain=2.2):
    """Lens blur, then a sensor whose white clips: the black squares shrink and no longer touch at the
    corners, as on the real 190 deg set."""
    img = cv2.GaussianBlur(image.astype(np.float32), (0, 0), sigma)
    return np.clip((img - 25) * gain + 25, 0, 255).astype(np.uint8)


def side_lit(image):
    ramp = np.linspace(-40, 40, image.shape[1], dtype=np.float32)[None, :]
    return np.clip(blurred(image).astype(np.float32) + ramp, 0, 255).astype(np.uint8)


def true_corners(cam, view):
    return cam.project(board_points(BOARD, SQUARE) @ exp_so3(view.rvec).T + view.tvec)[0]


def aligned(corners, truth):
    """The detector may start the grid at any corner: take the order that matches the truth."""
    g = corners.reshape(BOARD[1], BOARD[0], 2)
    return min((o.reshape(-1, 2) for o in (g, g[::-1, ::-1], g[::-1], g[:, ::-1])),
               key=lambda o: np.abs(o - truth).max())


@pytest.fixture(scope="module")
def renders():
    cam = fisheye()
    return cam, render_board_views(cam, BOARD, SQUARE, n_views=6, seed=11, noise_sigma=2.0)


@pytest.mark.parametrize("degrade", [lambda im: im, blurred, overexposed, side_lit],
                         ids=["sharp", "blurred", "overexposed", "side-lit"])
def test_corners_sit_on_the_true_corners(renders, degrade):
    cam, views = renders
    errors = []
    for view in views[:4]:
        corners = detect_corners(degrade(view.image), BOARD)
        assert corners is not None
        truth = true_corners(cam, view)
        errors.append(np.linalg.norm(aligned(corners, truth) - truth, axis=1))
    errors = np.concatenate(errors)
    # OpenCV's cornerSubPix, measured on the same overexposed renders, errs by 1.5 px at the median.
    assert np.median(errors) < 0.06
    assert np.percentile(errors, 90) < 0.15


def test_calibration_from_overexposed_renders(renders):
    cam, views = renders
    corners = [detect_corners(overexposed(v.image), BOARD) for v in views]
    res = calibrate_from_corners([c for c in corners if c is not None], BOARD, SQUARE, "polynomial", cam.width,
                                 cam.height, max_theta_deg=95)
    assert len(res.used) == 6
    assert res.rms_px < 0.1
    assert abs(res.camera.params[0] / cam.params[0] - 1) < 0.003
    assert np.hypot(*(res.camera.params[4:] - cam.params[4:])) < 0.3
    theta = np.radians(np.linspace(1, 80, 40))
    assert np.abs(res.camera._radius(theta)[0] - cam._radius(theta)[0]).max() < 0.3


def quadratic(s, t):
    return np.stack([300 + 20 * s - 3 * t + 0.8 * s * s + 0.3 * s * t, 200 + 2 * s + 18 * t - 0.5 * t * t], axis=-1)


def test_local_grid_reproduces_a_quadratic_map_and_its_jacobian():
    j, i = np.meshgrid(np.arange(BOARD[1]), np.arange(BOARD[0]), indexing="ij")
    corners = quadratic(i.ravel().astype(float), j.ravel().astype(float))
    coef = local_grids(corners, BOARD)
    q = np.random.default_rng(0).uniform(-0.6, 0.6, (len(corners), 5, 2))
    uv, D = grid_map(coef, q)
    # Each corner's grid is centred on it: board offsets are relative to the corner, at the edges too.
    assert np.allclose(uv, quadratic(i.ravel()[:, None] + q[..., 0], j.ravel()[:, None] + q[..., 1]), atol=1e-9)
    k = 7
    numeric = approx_derivative(lambda x: grid_map(coef[k:k + 1], x.reshape(1, 1, 2))[0].ravel(), q[k, 0],
                                method="3-point")
    assert np.allclose(D[k, 0], numeric, atol=1e-6)


def test_corners_without_a_corner_keep_their_place():
    rng = np.random.default_rng(0)
    start = np.stack(np.meshgrid(np.arange(9) * 20.0 + 200, np.arange(6) * 20.0 + 150), axis=-1).reshape(-1, 2)
    flat = np.full((480, 640), 128, np.uint8)
    noise = np.clip(128 + rng.normal(0, 3, flat.shape), 0, 255).astype(np.uint8)
    out, ok = refine_corners(flat, start, BOARD)
    assert not ok.any() and np.array_equal(out, start)
    # Noise alone has no centre of symmetry, though the fit may chance on a spot that looks like one.
    out, ok = refine_corners(noise, start, BOARD)
    assert ok.mean() < 0.1 and np.array_equal(out[~ok], start[~ok])
