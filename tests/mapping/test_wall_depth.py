"""The dense wall's depth search on a synthetic textured oval pipe seen from a camera moving along its axis."""

import cv2
import numpy as np
import pytest

from pipemap.camera import camera_from_dict
from pipemap.config import DeformationSettings
from pipemap.mapping.deformation import ring_fit, ring_profile
from pipemap.mapping.wall import WallPiece
from pipemap.mapping.wall_depth import slice_radii

R, A2 = 0.15, 0.003  # radius and the second harmonic's amplitude: D = 2R + 2 A2 cos 2 phi, ovality 4 %


def true_radius(phi):
    return R + A2 * np.cos(2 * phi)


@pytest.fixture(scope="module")
def scene():
    camera = camera_from_dict({"model": "polynomial", "width": 640, "height": 480, "max_theta_deg": 95.0,
                               "params": {"k1": 145.0, "k2": -4.0, "k3": 1.0, "k4": -0.2, "u0": 319.5, "v0": 239.5}})
    piece = WallPiece("S0", np.zeros(3), np.array([0.0, 0.0, 1.0]), R, np.array([0.0, -1.0, 0.0]))
    _, e_up, e_cw = piece.frame()
    rng = np.random.default_rng(0)
    texel = 0.001  # the albedo: seeded noise smoothed over ~2 mm, on a (h, arc) grid of 1 mm
    albedo = cv2.GaussianBlur(rng.uniform(0.2, 1.0, (1000, int(2 * np.pi * R / texel))).astype(np.float32), (0, 0), 1.5)
    u, v = np.meshgrid(np.arange(640.0), np.arange(480.0))
    bearing, ok = camera.unproject(np.stack([u, v], axis=-1))
    phi = np.mod(np.arctan2(bearing @ e_cw, bearing @ e_up), 2 * np.pi)
    rho = np.hypot(bearing @ e_cw, bearing @ e_up)
    poses, images = [], []
    for z in np.arange(0.0, 0.2, 0.02):
        t = true_radius(phi) / np.maximum(rho, 1e-9)  # the camera on the axis: a ray keeps its phi
        h = z + t * bearing[..., 2]
        grey = cv2.remap(albedo, (phi * R / texel).astype(np.float32), ((h + 0.2) / texel).astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        light = 0.03 / np.maximum(t, 0.05) ** 2 * rho  # the LED's fall-off moves with the camera
        images.append(np.where(ok & (rho > 0.05), np.clip(255 * grey * light, 0, 255), 0).astype(np.uint8))
        T = np.eye(4)
        T[2, 3] = z
        poses.append(T)
    return camera, piece, np.array(poses), images


def test_depth_search_finds_the_oval_wall(scene):
    camera, piece, poses, images = scene
    s = DeformationSettings()
    phi, r = slice_radii(piece, 0.25, camera, poses, lambda k: images[k].astype(np.float32), R, s)
    err = r - true_radius(phi)
    assert np.isfinite(r).mean() > 0.9
    assert np.nanmedian(np.abs(err)) < 0.0005  # sub-millimetre per cell
    coef, keep = ring_fit(phi, r, s)
    p = ring_profile(0.25, coef, int(keep.sum()), "S0", "dense", 0.0, 0.0, s.harmonics)
    assert p.ovality_pct == pytest.approx(200 * A2 / R, abs=0.3)  # 4 %
    assert p.diameter_y_m == pytest.approx(2 * R + 2 * A2, abs=0.0005)
    assert p.diameter_x_m == pytest.approx(2 * R - 2 * A2, abs=0.0005)
