"""Lucas-Kanade between keyframes (frontend/flow_tracker.py): sub-pixel at any density, blank frames refused."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipemap.dataset import Frame
from pipemap.frontend.flow_tracker import FlowTracker
from pipemap.sim.presets import fisheye_camera


def _texture(width: int, height: int, seed: int = 4) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tex = np.zeros((height, width), np.float32)
    for sigma in (1.5 * width / 640, 4.0 * width / 640):
        tex += cv2.GaussianBlur(rng.normal(size=(height, width)).astype(np.float32), (0, 0), sigma) * sigma
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return 40 + 180 * tex


def _shifted(image: np.ndarray, du: float, dv: float) -> np.ndarray:
    m = np.float32([[1, 0, du], [0, 1, dv]])
    return cv2.warpAffine(image, m, image.shape[::-1], flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


@pytest.mark.parametrize("size, shrink", [((640, 480), 1), ((1280, 960), 2)])
def test_features_are_followed_to_a_tenth_of_a_pixel_at_any_density(size, shrink):
    camera = fisheye_camera(*size)
    tracker = FlowTracker(camera)
    assert tracker._shrink == shrink  # the finer camera is followed on its image halved
    image = _texture(*size)
    shift = np.array([2.6, -1.3]) * size[0] / 640
    [keyframe] = tracker.process(Frame(0, 0.0, image))
    followed = tracker._follow(tracker.extract(Frame(1, 0.1, _shifted(image, *shift))))
    moved = followed.positions - keyframe.keypoints[followed.rows]
    assert len(followed.rows) > 0.9 * len(keyframe)
    assert np.allclose(np.median(moved, axis=0), shift, atol=0.05)
    assert np.mean(np.linalg.norm(moved - shift, axis=1) < 0.1 * shrink) > 0.9
    assert followed.median_flow == pytest.approx(np.linalg.norm(shift), abs=0.05)


def test_a_blank_frame_is_not_followed_and_the_next_is_followed_from_the_keyframe():
    camera = fisheye_camera(640, 480)
    tracker = FlowTracker(camera)
    image = _texture(640, 480)
    [keyframe] = tracker.process(Frame(0, 0.0, image))
    tracker.process(Frame(1, 0.1, _shifted(image, 1.0, 0.5)))
    assert tracker._candidate is not None
    blank = Frame(2, 0.2, np.full((480, 640), 255.0, np.float32))
    assert tracker._follow(tracker.extract(blank)) is None
    # the blank frame makes the last followed frame the keyframe; the blank one itself is lost
    made = tracker.process(blank)
    assert [k.index for k in made] == [1] and tracker._lost == 1
    assert tracker.process(Frame(3, 0.3, _shifted(image, 2.0, 1.0))) == [] and tracker._lost == 0
    assert np.allclose(np.median(tracker._positions - tracker._kf_features.keypoints[tracker._rows], axis=0),
                       [1.0, 0.5], atol=0.05)


def test_a_stall_is_bridged_by_each_features_speed():
    """After a stalled link the next frame has moved on several frames' worth. Searched from where each feature
    was, a one-level pyramid (15 px window) loses the 36 px jump; searched from where its speed takes it, it is
    found."""
    from pipemap.config import FrontendSettings

    camera = fisheye_camera(640, 480)
    tracker = FlowTracker(camera, FrontendSettings(flow_levels=1, keyframe_min_flow_px=100.0))
    image = _texture(640, 480)
    step = np.array([4.0, 2.0])  # px a frame, 0.1 s apart
    [keyframe] = tracker.process(Frame(0, 0.0, image))
    for i in (1, 2):
        tracker.process(Frame(i, 0.1 * i, _shifted(image, *(i * step))))
    stalled = tracker.extract(Frame(8, 0.8, _shifted(image, *(8 * step))))  # six frames lost
    followed = tracker._follow(stalled)
    moved = followed.positions - keyframe.keypoints[followed.rows]
    assert np.allclose(np.median(moved, axis=0), 8 * step, atol=0.05)
    assert np.allclose(np.median(followed.velocities, axis=0), 10 * step, atol=0.5)
    tracker._velocities[:] = 0.0  # at rest, the same frame is not found
    lost = tracker._follow(stalled)
    assert lost is None or np.median(np.linalg.norm(lost.positions - keyframe.keypoints[lost.rows] - 8 * step,
                                                    axis=1)) > 1.0


def test_a_robot_turning_back_is_followed_from_rest():
    """Where the robot turns back, the guess from each feature's speed lies two steps off; the search from where
    the features were finds them (a one-level pyramid: neither the guess nor the keyframe, 20 px away, would)."""
    from pipemap.config import FrontendSettings

    camera = fisheye_camera(640, 480)
    tracker = FlowTracker(camera, FrontendSettings(flow_levels=1, keyframe_min_flow_px=100.0))
    image = _texture(640, 480)
    step = np.array([6.0, 3.0])
    [keyframe] = tracker.process(Frame(0, 0.0, image))
    for i in (1, 2, 3, 4):
        assert tracker.process(Frame(i, 0.1 * i, _shifted(image, *(i * step)))) == []
    back = tracker.extract(Frame(5, 0.5, _shifted(image, *(3 * step))))
    followed = tracker._follow(back)
    moved = followed.positions - keyframe.keypoints[followed.rows]
    assert np.allclose(np.median(moved, axis=0), 3 * step, atol=0.05)
