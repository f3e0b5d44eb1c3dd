"""Camera effects descriptions: profiles, YAML, the gain curve, the link schedule, the overlay layout."""

from datetime import datetime

import numpy as np
import pytest
import yaml

from pipemap.errors import PipemapError
from pipemap.sim.effects import (DROP, PROFILES, REPEAT, WRITTEN, CameraEffects, Gain, Link, gain_curve, link_schedule,
                                 load_effects)
from pipemap.sim.overlay import OUTLINE, OverlayPainter


def test_profiles_validate_and_clean_is_clean():
    for name in PROFILES:
        fx = load_effects(name)
        assert fx.clean == (name == "clean")
    h264 = load_effects("cctv-h264")
    assert h264.video.codec == "h264" and h264.video.crf == 28
    assert h264.overlay.distance and h264.overlay.clock and h264.gain.drift == (0.75, 1.3) and len(h264.gain.steps) == 2
    assert (h264.link.repeat_rate, h264.link.drop_rate) == (0.05, 0.01)
    assert load_effects(None).clean and load_effects(CameraEffects()).clean


def test_yaml_starts_from_a_profile_and_errors_name_the_key(tmp_path):
    spec = tmp_path / "fx.yaml"
    spec.write_text(yaml.safe_dump({"profile": "cctv-h264", "video": {"crf": 35}, "interlace": True}))
    fx = load_effects(spec)
    assert fx.video.crf == 35 and fx.video.codec == "h264" and fx.interlace and fx.link.repeat_rate == 0.05
    spec.write_text(yaml.safe_dump({"gain": {"drift": [1.3, 0.75]}}))
    with pytest.raises(PipemapError, match="low <= high") as e:
        load_effects(spec)
    assert str(spec) in e.value.line() and "gain" in e.value.line()
    spec.write_text(yaml.safe_dump({"video": {"codec": "h265"}}))
    with pytest.raises(PipemapError, match="video.codec"):
        load_effects(spec)
    with pytest.raises(PipemapError, match="unknown camera effects 'nope'"):
        load_effects("nope")
    with pytest.raises(PipemapError, match="exactly one of frame or fraction"):
        load_effects({"gain": {"steps": [{"factor": 1.2}]}})
    with pytest.raises(PipemapError, match="below 1"):
        load_effects({"link": {"repeat_rate": 0.6, "drop_rate": 0.5}})


def test_gain_drift_spans_its_range_and_steps_jump_by_their_factor():
    n = 200
    drift = gain_curve(Gain(drift=(0.75, 1.3)), n, seed=1)
    assert drift.min() == pytest.approx(0.75) and drift.max() == pytest.approx(1.3)
    assert np.max(np.abs(np.diff(np.log(drift)))) < 0.05  # slow: under 5 % from one frame to the next
    steps = [{"frame": 50, "factor": 1.2}, {"fraction": 0.7, "factor": 0.8}]
    stepped = gain_curve(Gain(drift=(0.75, 1.3), steps=steps), n, seed=1)
    ratio = stepped / drift
    np.testing.assert_allclose(ratio[:50], 1.0)
    np.testing.assert_allclose(ratio[50:140], 1.2)
    np.testing.assert_allclose(ratio[140:], 1.2 * 0.8)
    flicker = gain_curve(Gain(flicker=0.03), n, seed=1)
    assert 0.97 <= flicker.min() < 0.975 and 1.025 < flicker.max() <= 1.03
    assert not np.allclose(gain_curve(Gain(drift=(0.75, 1.3)), n, seed=2), drift)  # seeded
    np.testing.assert_array_equal(gain_curve(Gain(), n, seed=1), 1.0)


def test_link_schedule_has_exact_counts_at_seeded_places():
    kinds = link_schedule(Link(repeat_rate=0.05, drop_rate=0.01), 201, seed=3)
    assert kinds[0] == WRITTEN
    assert np.sum(kinds == REPEAT) == 10 and np.sum(kinds == DROP) == 2
    np.testing.assert_array_equal(kinds, link_schedule(Link(repeat_rate=0.05, drop_rate=0.01), 201, seed=3))
    assert not np.array_equal(kinds, link_schedule(Link(repeat_rate=0.05, drop_rate=0.01), 201, seed=4))
    assert np.all(link_schedule(Link(), 50, seed=3) == WRITTEN)


def test_overlay_texts_stay_in_their_boxes_and_static_text_does_not_change():
    spec = load_effects({"overlay": {"manhole": "MH1034 > MH1035"}}).overlay
    for width, height in ((160, 120), (640, 480), (720, 576)):
        painter = OverlayPainter(spec, width, height)
        inside = np.zeros((height, width), bool)
        for x0, y0, x1, y1 in painter.boxes.values():
            inside[y0:y1, x0:x1] = True
        static = None
        for distance, seconds in ((0.0, 0.0), (-1234.56, 59.9), (8888.88, 3601.0)):
            img = np.full((height, width), 128, np.uint8)
            mask = painter.draw(img, distance, seconds)
            assert mask.any() and not (mask & ~inside).any()
            assert set(np.unique(img[mask])) == {OUTLINE, 255} and np.all(img[~mask] == 128)
            x0, y0, x1, y1 = painter.boxes["manhole"]
            if static is None:
                static = img[y0:y1, x0:x1].copy()
            np.testing.assert_array_equal(img[y0:y1, x0:x1], static)
    assert painter.texts(12.345, 61.5) == {"clock": "2024-03-18 10:16:01", "manhole": "MH1034 > MH1035",
                                           "distance": "12.35 m"}
    assert spec.start == datetime(2024, 3, 18, 10, 15)
