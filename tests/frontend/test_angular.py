"""The front end's pixel settings follow the camera's pixel density (frontend/angular.py)."""

from __future__ import annotations

import pytest

from pipemap.config import ClassificationSettings, FrontendSettings
from pipemap.frontend.angular import classification_for, frontend_for, pixel_scale, pixels_per_degree
from pipemap.sim.presets import cctv_camera, fisheye_camera


def test_reference_is_the_fisheye_at_640():
    reference = FrontendSettings().reference_px_per_deg
    assert pixels_per_degree(fisheye_camera(640, 480)) == pytest.approx(reference, rel=1e-3)
    assert pixel_scale(fisheye_camera(1280, 960), 2.53) == pytest.approx(2.0, rel=1e-3)
    # the 100 deg CCTV lens puts 2.5 times as many pixels on a degree at the same image size
    assert pixel_scale(cctv_camera(640, 480), 2.53) == pytest.approx(2.48, abs=0.01)


def test_motion_scales_both_ways_patches_only_up():
    s = FrontendSettings()
    fine = frontend_for(fisheye_camera(1280, 960), s)
    coarse = frontend_for(fisheye_camera(320, 240), s)
    assert fine.keyframe_min_flow_px == pytest.approx(2 * s.keyframe_min_flow_px, rel=1e-3)
    assert coarse.keyframe_min_flow_px == pytest.approx(0.5 * s.keyframe_min_flow_px, rel=1e-3)
    assert (fine.max_flow_px, coarse.max_flow_px) == pytest.approx((160, 40), rel=1e-3)
    assert (fine.guided_search_px, coarse.guided_search_px) == (16, 4)
    assert (fine.template_window, fine.zncc_patch, fine.min_distance_px) == (63, 23, 6)
    assert fine.harris_block_px in (5, 7) and fine.harris_block_px % 2 == 1
    assert (coarse.template_window, coarse.zncc_patch, coarse.harris_block_px, coarse.min_distance_px) == (
        s.template_window, s.zncc_patch, s.harris_block_px, s.min_distance_px)
    assert coarse.lighting_sigma_px == pytest.approx(0.5 * s.lighting_sigma_px, rel=1e-3)
    assert fine.reference_px_per_deg is None and frontend_for(fisheye_camera(1280, 960), fine) is fine


def test_no_reference_keeps_the_pixels():
    s = FrontendSettings(reference_px_per_deg=None)
    assert frontend_for(fisheye_camera(1280, 960), s) is s


def test_classification_subsampling_keeps_the_reference_density():
    c = ClassificationSettings()
    assert classification_for(fisheye_camera(1280, 960), c, 2.53).subsample == 4
    assert classification_for(fisheye_camera(320, 240), c, 2.53).subsample == 1
    assert classification_for(fisheye_camera(320, 240), c, None) is c
