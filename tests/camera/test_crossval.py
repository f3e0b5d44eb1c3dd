"""Cross-validation of a calibration on seeded synthetic corners: a model that fits the lens predicts held-back
views at the training error; folds are dealt reproducibly; bad requests are PipemapErrors."""

import numpy as np
import pytest

from pipemap.camera import PolynomialCamera
from pipemap.camera.calibration import board_points
from pipemap.camera.crossval import cross_validate
from pipemap.errors import PipemapError
from pipemap.geometry.rotations import exp_so3
from pipemap.sim.board import random_board_poses

BOARD, SQUARE = (9, 6), 0.025


def fisheye_190():
    return PolynomialCamera(1280, 960, dict(k1=290.0, k2=-2.5, k3=0.8, k4=-0.15, u0=641.2, v0=478.3), 95)


def corner_views(cam, n_views, seed, noise_px=0.3):
    rng = np.random.default_rng(seed)
    obj = board_points(BOARD, SQUARE)
    return [cam.project(obj @ exp_so3(r).T + t)[0] + rng.normal(0.0, noise_px, (len(obj), 2))
            for r, t in random_board_poses(cam, BOARD, SQUARE, n_views, rng)]


def validate(cam, views, **kw):
    return cross_validate(views, BOARD, SQUARE, "polynomial", cam.width, cam.height, max_theta_deg=95, **kw)


def test_held_out_views_reproject_at_the_training_error():
    cam = fisheye_190()
    cv = validate(cam, corner_views(cam, 12, seed=2), folds=4)
    assert cv.folds == 4 and len(cv.train_rms) == 4 and len(cv.held_out_rms) == 12
    # 0.3 px per coordinate: 0.42 px per corner. Each held-back pose has 6 unknowns against 108 numbers and
    # each fold's intrinsics carry the noise of 9 views, so the held-out error sits a few per cent above.
    assert 0.38 < cv.train_rms_px < 0.45
    assert cv.train_rms_px < cv.held_out_rms_px < 1.1 * cv.train_rms_px
    assert max(cv.held_out_rms) < 0.6
    assert all(n == 54 for n in cv.held_out_corners)


def test_folds_are_dealt_reproducibly_and_leave_one_out_by_default():
    cam = fisheye_190()
    views = corner_views(cam, 6, seed=3)
    loo = validate(cam, views)
    assert loo.folds == 6 and loo.fold_of_view == [0, 1, 2, 3, 4, 5]
    a, b = validate(cam, views, folds=2, seed=7), validate(cam, views, folds=2, seed=7)
    assert a.fold_of_view == b.fold_of_view and a.fold_of_view != [0, 1] * 3
    assert list(np.bincount(a.fold_of_view)) == [3, 3]
    assert a.held_out_rms == b.held_out_rms


def test_bad_requests_are_pipemap_errors():
    cam = fisheye_190()
    views = corner_views(cam, 4, seed=4)
    with pytest.raises(PipemapError, match="at least 2 folds"):
        validate(cam, views, folds=1)
    with pytest.raises(PipemapError, match="at least 4 views"):
        validate(cam, views[:3])
