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


def test_a_feature_continues_when_the_refined_pose_takes_it_though_ransac_did_not():
    """With frontend.continue_on_refined_pose, tracks continue within track_threshold_factor x the RANSAC threshold
    of the refined pose (as with descriptors), not only where RANSAC's own pose counted them: on compressed footage
    that ended a tenth of the followed features every keyframe."""
    from pipemap.frontend.flow_tracker import consistent_with_pose
    from pipemap.frontend.relpose import essential_from_pose, estimate_relative_pose, refine_pose, sampson_angle
    from pipemap.geometry.rotations import exp_so3

    rng = np.random.default_rng(3)
    n = 600
    # wall points of a 0.2 m pipe ahead of the camera; the camera moves 2 cm on and turns 1 deg
    h = rng.uniform(0.1, 1.5, n)
    a = rng.uniform(0, 2 * np.pi, n)
    X = np.stack([0.2 * np.cos(a), 0.2 * np.sin(a), h], axis=1)
    R = exp_so3(np.radians([0.3, 1.0, 0.2]))
    t_cam = np.array([0.001, 0.0, 0.02])
    bi = X / np.linalg.norm(X, axis=1, keepdims=True)
    Xj = (X - t_cam) @ R  # the second camera's frame: X_i = R X_j + t_cam
    bj = Xj / np.linalg.norm(Xj, axis=1, keepdims=True)
    threshold = np.radians(0.1)
    # move a third of the features off their epipolar circles: 1.3-1.7 x and 2.5-3 x the threshold (Sampson)
    E = essential_from_pose(*_pose_between(bi, bj))
    normal = bi @ E.T  # E b_i: the epipolar circle's normal in the second view
    normal -= np.sum(normal * bj, axis=1, keepdims=True) * bj
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    near, far = np.arange(0, 100), np.arange(100, 200)
    want = np.zeros(n)
    want[near] = rng.uniform(1.3, 1.7, len(near)) * threshold
    want[far] = rng.uniform(2.5, 3.0, len(far)) * threshold
    for _ in range(3):  # the Sampson error is about proportional to the move; settle the factor
        s = sampson_angle(E, bi, bj)
        moved = want > 0
        step = np.where(moved, want - s, 0.0)
        bj = bj + step[:, None] * normal * np.sqrt(2.0)
        bj /= np.linalg.norm(bj, axis=1, keepdims=True)
    s = sampson_angle(E, bi, bj)
    assert np.allclose(s[near] / threshold, want[near] / threshold, atol=0.05)
    pose = estimate_relative_pose(bi, bj, threshold, 0.999, np.random.default_rng(0), 500, refine=False)
    assert not pose.inliers[near].any()  # RANSAC's pose counts none of the near ones ...
    Rr, tr = refine_pose(pose.R, pose.t, bi[pose.inliers], bj[pose.inliers], threshold)
    keep = consistent_with_pose(Rr, tr, bi, bj, 2.0 * threshold)
    assert keep[near].all()  # ... the refined pose takes them all
    assert not keep[far].any()
    assert keep[200:].all()


def _pose_between(bi: np.ndarray, bj: np.ndarray):
    from pipemap.frontend.relpose import estimate_relative_pose

    pose = estimate_relative_pose(bi, bj, np.radians(0.01), 0.999, np.random.default_rng(1), 500)
    return pose.R, pose.t


@pytest.mark.parametrize("on", [False, True])
def test_the_setting_decides_whether_features_ransac_left_out_continue(monkeypatch, on):
    """The keyframe promotion itself: features RANSAC's pose leaves out continue their tracks only with
    frontend.continue_on_refined_pose (RANSAC here made to leave out every fifth of its inliers)."""
    from dataclasses import replace

    import pipemap.frontend.flow_tracker as flow_tracker
    from pipemap.config import FrontendSettings

    real = flow_tracker.estimate_relative_pose
    counted = {}

    def ransac_leaving_some_out(bi, bj, *args, **kwargs):
        pose = real(bi, bj, *args, **kwargs)
        keep = pose.inliers.copy()
        keep[::5] = False  # RANSAC's own pose leaves out every fifth feature of its inliers
        counted["left_out"] = int(pose.inliers.sum() - keep.sum())
        counted["kept"] = int(keep.sum())
        return replace(pose, inliers=keep)

    monkeypatch.setattr(flow_tracker, "estimate_relative_pose", ransac_leaving_some_out)
    camera = fisheye_camera(640, 480)
    tracker = FlowTracker(camera, FrontendSettings(continue_on_refined_pose=on))
    image = _texture(640, 480)
    [first] = tracker.process(Frame(0, 0.0, image))
    made = []
    for i in range(1, 8):  # 2 px a frame: a keyframe once the median flow passes 10 px
        made += tracker.process(Frame(i, 0.1 * i, _shifted(image, 2.0 * i, 0.0)))
    assert made, "no keyframe was made"
    continued = int(made[0].inliers.sum())
    assert counted["left_out"] > 50
    if on:  # the refined pose takes most of those RANSAC left out
        assert continued > counted["kept"] + 0.8 * counted["left_out"]
    else:
        assert continued <= counted["kept"]


def test_corners_found_beside_the_anchor_match_make_the_same_keyframes():
    from concurrent.futures import ThreadPoolExecutor

    camera = fisheye_camera(640, 480)
    image = _texture(640, 480)
    frames = [Frame(i, 0.1 * i, _shifted(image, 2.5 * i, 0.8 * i)) for i in range(12)]
    inline = FlowTracker(camera)
    made = [k for f in frames for k in inline.process(f)]
    beside = FlowTracker(camera)
    with ThreadPoolExecutor(max_workers=1) as pool:
        beside.beside = pool.submit
        made_beside = [k for f in frames for k in beside.process(f)]
    assert len(made) >= 3 and len(made) == len(made_beside)
    for a, b in zip(made, made_beside):
        assert a.index == b.index
        assert np.array_equal(a.keypoints, b.keypoints) and np.array_equal(a.track_ids, b.track_ids)
