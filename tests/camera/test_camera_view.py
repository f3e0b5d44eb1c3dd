"""The camera's view as colatitudes: what the network pipeline's bands are derived from."""

import numpy as np
import pytest

from pipemap.camera import PinholeCamera
from pipemap.mapping.appearance import colatitude_band
from pipemap.config import AppearanceSettings
from pipemap.sim.presets import cctv_camera, fisheye_camera


def test_pinhole_view_reaches_the_image_edges_and_corners():
    w, h, f = 640, 480, 300.0
    cam = PinholeCamera(w, h, dict(fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2, k1=0, k2=0, p1=0, p2=0, k3=0))
    inscribed, widest = np.degrees(cam.view_colatitudes())
    # the image ends half a pixel beyond its outer pixel centres; sampled every 0.1 deg
    assert inscribed == pytest.approx(np.degrees(np.arctan((h / 2) / f)), abs=0.15)
    assert widest == pytest.approx(np.degrees(np.arctan(np.hypot(w / 2, h / 2) / f)), abs=0.15)


def test_fisheye_circle_inside_the_image_sees_its_whole_field():
    inscribed, widest = np.degrees(fisheye_camera(640, 480).view_colatitudes())
    assert inscribed == pytest.approx(95.0) and widest == pytest.approx(95.0)


def test_appearance_band_follows_the_view():
    s = AppearanceSettings()
    assert colatitude_band(s, fisheye_camera(640, 480)) == (50.0, 90.0)  # the paper's band
    lo, hi = colatitude_band(s, cctv_camera())
    assert hi == pytest.approx(np.degrees(cctv_camera().view_colatitudes()[1]))
    assert lo == pytest.approx(hi * 5 / 9) and 55 < hi < 60
    assert colatitude_band(AppearanceSettings(min_theta_deg=20.0), cctv_camera())[0] == 20.0
