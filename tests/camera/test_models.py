"""Camera models: round trips, Jacobians against numerical ones, OpenCV as the oracle, bad input."""

import cv2
import numpy as np
import pytest

from pipemap.camera import KannalaBrandtCamera, PinholeCamera, PolynomialCamera, camera_from_dict
from pipemap.errors import PipemapError


def fisheye_190():
    return PolynomialCamera(1280, 960, dict(k1=290.0, k2=-2.5, k3=0.8, k4=-0.15, u0=641.2, v0=478.3), 95)


def kb():
    return KannalaBrandtCamera(
        1280, 960, dict(fx=300.0, fy=302.0, cx=640.4, cy=481.1, k1=0.02, k2=-0.01, k3=0.003, k4=-0.0005), 95)


def pinhole():
    return PinholeCamera(
        1024, 768, dict(fx=730.0, fy=731.5, cx=512.3, cy=383.2, k1=-0.28, k2=0.09, p1=0.001, p2=-0.0007, k3=-0.01))


CAMERAS = [fisheye_190, kb, pinhole]


def image_grid(cam, step=7.3):
    u, v = np.meshgrid(np.arange(-0.5, cam.width - 0.5, step), np.arange(-0.5, cam.height - 0.5, step))
    return np.stack([u, v], -1)


@pytest.mark.parametrize("make", CAMERAS)
def test_round_trip_over_the_whole_image(make):
    cam = make()
    uv = image_grid(cam)
    bearings, valid = cam.unproject(uv)
    assert np.allclose(np.linalg.norm(bearings, axis=-1), 1.0, atol=1e-12)
    back, valid2 = cam.project(bearings * 3.7)
    err = np.abs(back - uv)[valid]
    assert valid.sum() > 0.4 * valid.size
    assert err.max() < 1e-6
    assert np.all(valid2[valid])


@pytest.mark.parametrize("make", [fisheye_190, kb])
def test_fisheye_sees_backwards_beyond_90_degrees(make):
    cam = make()
    theta = np.radians(np.linspace(0, 95, 400))
    phi = np.linspace(-np.pi, np.pi, 400)
    X = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    uv, valid = cam.project(X)
    b, valid_b = cam.unproject(uv)
    ok = valid & valid_b
    assert ok[theta > np.radians(90.5)].sum() > 5  # backwards rays land inside the image
    assert np.linalg.norm(b - X, axis=-1)[ok].max() < 1e-9
    # the circle's points beyond max_theta are marked invalid
    X_out = np.array([[np.sin(np.radians(100)), 0, np.cos(np.radians(100))]])
    assert not cam.project(X_out)[1][0]


@pytest.mark.parametrize("shape", [(7,), (3, 5), (2, 3, 4)])
@pytest.mark.parametrize("make", CAMERAS)
def test_batch_shapes(make, shape):
    cam = make()
    rng = np.random.default_rng(1)
    X = rng.normal(size=shape + (3,))
    X[..., 2] = np.abs(X[..., 2]) + 1
    uv, valid = cam.project(X)
    assert uv.shape == shape + (2,) and valid.shape == shape
    b, v = cam.unproject(uv)
    assert b.shape == shape + (3,) and v.shape == shape
    uv2, Jp, Jk = cam.project_jacobian(X)
    assert Jp.shape == shape + (2, 3) and Jk.shape == shape + (2, len(cam.param_names))


@pytest.mark.parametrize("make", CAMERAS)
def test_jacobians_match_numerical(make):
    cam = make()
    rng = np.random.default_rng(2)
    theta = rng.uniform(0.01, np.radians(94 if cam.model != "pinhole" else 40), 200)
    phi = rng.uniform(-np.pi, np.pi, 200)
    depth = rng.uniform(0.2, 5.0, 200)
    X = depth[:, None] * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    _, Jp, Jk = cam.project_jacobian(X)
    eps = 1e-6
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        num = (cam.project(X + d)[0] - cam.project(X - d)[0]) / (2 * eps)
        np.testing.assert_allclose(Jp[..., i], num, rtol=1e-5, atol=1e-4)
    for i in range(len(cam.param_names)):
        d = np.zeros(len(cam.param_names))
        d[i] = eps
        num = (cam.with_params(cam.params + d).project(X)[0]
               - cam.with_params(cam.params - d).project(X)[0]) / (2 * eps)
        np.testing.assert_allclose(Jk[..., i], num, rtol=1e-5, atol=1e-4)


def test_jacobian_on_the_optical_axis_is_the_limit():
    cam = fisheye_190()
    _, Jp, _ = cam.project_jacobian(np.array([0.0, 0.0, 2.0]))
    np.testing.assert_allclose(Jp, [[290.0 / 2, 0, 0], [0, 290.0 / 2, 0]], atol=1e-9)


def test_kannala_brandt_agrees_with_opencv_fisheye():
    cam = kb()
    rng = np.random.default_rng(3)
    theta = rng.uniform(0, np.radians(89), 500)
    phi = rng.uniform(-np.pi, np.pi, 500)
    X = (np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
         * rng.uniform(0.5, 3, (500, 1)))
    fx, fy, cx, cy, k1, k2, k3, k4 = cam.params
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    ref, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.array([k1, k2, k3, k4]))
    ours, _ = cam.project(X)
    assert np.abs(ref.reshape(-1, 2) - ours).max() < 1e-6


def test_pinhole_agrees_with_opencv():
    cam = pinhole()
    rng = np.random.default_rng(4)
    X = (np.column_stack([rng.uniform(-0.6, 0.6, 500), rng.uniform(-0.45, 0.45, 500), np.ones(500)])
         * rng.uniform(0.5, 3, (500, 1)))
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = cam.params
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    ref, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, np.array([k1, k2, p1, p2, k3]))
    ours, _ = cam.project(X)
    assert np.abs(ref.reshape(-1, 2) - ours).max() < 1e-6


def test_pinhole_marks_points_behind_invalid():
    cam = pinhole()
    assert not cam.project(np.array([0.01, 0.0, -1.0]))[1]


def test_dict_round_trip():
    for make in CAMERAS:
        cam = make()
        again = camera_from_dict(cam.to_dict())
        assert type(again) is type(cam) and np.array_equal(again.params, cam.params)


@pytest.mark.parametrize(
    "block, words",
    [
        ({"model": "polynomial", "width": 640, "height": 480,
          "params": dict(k1=-100, k2=0, k3=0, k4=0, u0=320, v0=240)}, "k1"),
        ({"model": "kannala_brandt", "width": 640, "height": 480,
          "params": dict(fx=0, fy=300, cx=320, cy=240, k1=0, k2=0, k3=0, k4=0)}, "fx"),
        ({"model": "polynomial", "width": 640, "height": 480,
          "params": dict(k1=150, k2=-60, k3=0, k4=0, u0=320, v0=240), "max_theta_deg": 95}, "monotone"),
        ({"model": "pinhole", "width": 640, "height": 480,
          "params": dict(fx=300, fy=300, cx=320, cy=240, k1=-2.0, k2=0, p1=0, p2=0, k3=0)}, "monotone"),
        ({"model": "orthographic", "width": 640, "height": 480, "params": {}}, "unknown camera model"),
        ({"model": "pinhole", "width": 640, "height": 480, "params": dict(fx=300, fy=300, cx=320, cy=240)}, "missing"),
        ({"model": "pinhole", "width": 0, "height": 480,
          "params": dict(fx=300, fy=300, cx=320, cy=240, k1=0, k2=0, p1=0, p2=0, k3=0)}, "positive"),
    ],
)
def test_bad_parameters_raise_one_clear_error(block, words):
    with pytest.raises(PipemapError) as info:
        camera_from_dict(block, "dataset.yaml")
    line = str(info.value)
    assert "dataset.yaml" in line and words in line and "\n" not in line
