"""Rendered calibration boards: placement inside the field of view, correct squares, determinism, files."""

import numpy as np
import pytest
import yaml

from pipemap.camera import PinholeCamera, PolynomialCamera, load_camera
from pipemap.errors import PipemapError
from pipemap.geometry.rotations import exp_so3
from pipemap.sim.board import (BACKGROUND, BLACK, OUTSIDE_FOV, WHITE, inner_corners, random_board_poses,
                               render_board_views, save_board_views)

BOARD, SQUARE = (9, 6), 0.025


def small_fisheye():
    return PolynomialCamera(320, 240, dict(k1=72.5, k2=-0.5, k3=0.2, k4=-0.04, u0=160.3, v0=119.6), 95)


def small_pinhole():
    return PinholeCamera(320, 240, dict(fx=260.0, fy=261.0, cx=160.2, cy=119.7, k1=-0.2, k2=0.05, p1=0, p2=0, k3=0))


@pytest.mark.parametrize("make", [small_fisheye, small_pinhole])
def test_poses_keep_the_board_inside_the_image(make):
    cam = make()
    poses = random_board_poses(cam, BOARD, SQUARE, 12, rng=0, min_square_px=4.0)
    assert len(poses) == 12
    thetas = []
    for rvec, tvec in poses:
        X = inner_corners(BOARD, SQUARE) @ exp_so3(rvec).T + tvec
        _, valid = cam.project(X)
        assert valid.all()
        thetas.append(np.degrees(cam.colatitude(X)).max())
    if cam.model == "polynomial":
        assert max(thetas) > 75  # the fisheye periphery is sampled


def test_squares_have_the_right_colours():
    cam = small_fisheye()
    view = render_board_views(cam, BOARD, SQUARE, n_views=1, seed=3, noise_sigma=0.0)[0]
    img = view.image.astype(float)
    R, t = exp_so3(view.rvec), view.tvec
    nx, ny = BOARD
    i, j = np.meshgrid(np.arange(-1, nx), np.arange(-1, ny))
    centres = np.stack([(i.ravel() + 0.5) * SQUARE, (j.ravel() + 0.5) * SQUARE, np.zeros(i.size)], -1)
    uv, valid = cam.project(centres @ R.T + t)
    assert valid.all()
    shade = img[np.rint(uv[:, 1]).astype(int), np.rint(uv[:, 0]).astype(int)]
    dark = (i.ravel() + j.ravel()) % 2 == 0
    assert np.all(np.abs(shade[dark] - BLACK) < 20) and np.all(np.abs(shade[~dark] - WHITE) < 20)
    # The white margin, the grey background and the black outside of the image circle.
    margin = np.array([[-1.5 * SQUARE, -1.5 * SQUARE, 0.0]])
    uv_m, _ = cam.project(margin @ R.T + t)
    assert abs(img[int(round(uv_m[0, 1])), int(round(uv_m[0, 0]))] - WHITE) < 20
    assert img[0, 0] == OUTSIDE_FOV
    assert np.mean(img == BACKGROUND) > 0.1


def test_rendering_is_deterministic_and_noisy():
    cam = small_fisheye()
    a = render_board_views(cam, BOARD, SQUARE, n_views=2, seed=1)
    b = render_board_views(cam, BOARD, SQUARE, n_views=2, seed=1)
    c = render_board_views(cam, BOARD, SQUARE, n_views=2, seed=2)
    assert all(np.array_equal(x.image, y.image) for x, y in zip(a, b))
    assert not np.array_equal(a[0].image, c[0].image)
    assert a[0].image.dtype == np.uint8 and a[0].image.shape == (240, 320)
    # Anti-aliasing leaves intermediate grey levels along the square edges.
    clean = render_board_views(cam, BOARD, SQUARE, n_views=1, seed=1, noise_sigma=0.0)[0].image
    assert len(np.unique(clean)) > 10


def test_save_board_views_writes_images_and_true_camera(tmp_path):
    cam = small_pinhole()
    paths = save_board_views(tmp_path, cam, BOARD, SQUARE, n_views=3, seed=0)
    assert [p.name for p in paths] == ["000000.png", "000001.png", "000002.png"]
    assert all(p.is_file() for p in paths)
    assert np.allclose(load_camera(tmp_path / "camera.yaml").params, cam.params)
    truth = yaml.safe_load((tmp_path / "camera.yaml").read_text())["calibration_truth"]
    assert truth["board"] == "9x6" and len(truth["poses"]) == 3 and truth["poses"][0]["image"] == "images/000000.png"


def test_a_board_that_cannot_fit_is_a_pipemap_error():
    tiny = PinholeCamera(40, 30, dict(fx=30.0, fy=30.0, cx=19.5, cy=14.5, k1=0, k2=0, p1=0, p2=0, k3=0))
    with pytest.raises(PipemapError, match="could place only"):
        random_board_poses(tiny, BOARD, SQUARE, 2, rng=0, max_tries=20)
