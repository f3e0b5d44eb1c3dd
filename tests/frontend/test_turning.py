"""Bends the images do not show: the keyframes' viewing direction turning beyond a crawler's wobble."""

import numpy as np

from pipemap.frontend.tracks import Keyframe
from pipemap.frontend.turning import turning_keyframes, viewing_directions
from pipemap.geometry.rotations import exp_so3


def _keyframes(yaw_deg: np.ndarray, rng) -> list[Keyframe]:
    """Keyframes whose camera yaws by the given angles (deg) plus a wobble of up to 1 deg in roll and pitch."""
    wobble = np.radians(1.0) * np.sin(np.arange(len(yaw_deg)) / 7.0)[:, None] * np.array([1.0, 0.0, 1.0])
    R_wc = [exp_so3(np.array([0.0, np.radians(y), 0.0]) + w) for y, w in zip(np.cumsum(yaw_deg), wobble)]
    out = []
    for k in range(len(R_wc)):
        R = np.eye(3) if k == 0 else R_wc[k].T @ R_wc[k - 1]  # X_this = R X_prev
        out.append(Keyframe(k, k, float(k), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, np.int64),
                            np.zeros(0, bool), np.zeros(0, bool), R, np.zeros(3), k > 0))
    return out


def test_chained_directions_follow_the_yaw():
    kfs = _keyframes(np.full(40, 1.0), np.random.default_rng(0))
    z, chain = viewing_directions(kfs)
    assert np.all(chain == 0)
    turned = np.degrees(np.arccos(np.clip(z[0] @ z[-1], -1, 1)))
    assert abs(turned - 39.0) < 2.5  # 39 deg of yaw, give or take the wobble's pitch


def test_a_sweeping_bend_is_found_and_the_straight_pipe_either_side_is_not():
    yaw = np.zeros(300)
    yaw[120:180] = 0.5  # 30 deg over 60 keyframes: a bend of ten diameters
    turning = turning_keyframes(_keyframes(yaw, np.random.default_rng(1)), 20, 4.0)
    assert turning[125:175].all()
    assert not turning[:90].any() and not turning[210:].any()


def test_a_lost_track_starts_a_new_chain():
    import dataclasses

    kfs = _keyframes(np.full(60, 0.5), np.random.default_rng(2))
    kfs[30] = dataclasses.replace(kfs[30], pose_valid=False)
    assert viewing_directions(kfs)[1].max() == 1
    turning = turning_keyframes(kfs, 20, 4.0)
    assert turning[10:20].all() and turning[40:50].all()


def test_a_classified_junction_is_left_to_the_classification():
    yaw = np.zeros(200)
    yaw[95:105] = 9.0  # a tee's 90 deg turn over ten keyframes, which the images see
    classified = np.zeros(200, bool)
    classified[90:110] = True
    turning = turning_keyframes(_keyframes(yaw, np.random.default_rng(3)), 20, 4.0, classified)
    assert not turning.any()
    assert turning_keyframes(_keyframes(yaw, np.random.default_rng(3)), 20, 4.0)[80:120].all()


def test_a_short_run_next_to_a_classified_junction():
    yaw = np.zeros(30)
    yaw[10:15] = 3.0
    classified = np.zeros(30, bool)
    classified[12] = True
    assert not turning_keyframes(_keyframes(yaw, np.random.default_rng(4)), 20, 4.0, classified).any()


def test_the_turn_window_spans_the_same_pipe_at_any_keyframe_spacing():
    """Elbow-cross A's end as keyframes every 20 px of flow (twice the default's) make it: a classified 45 deg
    elbow, 18 keyframes of straight pipe, a sweeping 30 deg bend over 45 keyframes and 12 keyframes of straight
    pipe to the end of the route. The window given for the default spacing (20 keyframes) reaches from the bend
    to the route's end, so the bend swallows the straight pipe after it; scaled to the spacing (10) it does not."""
    from pipemap.config import Settings
    from pipemap.pipeline import turn_window

    yaw = np.zeros(185)
    yaw[100:110] = 4.5
    yaw[128:173] = 30.0 / 45
    classified = np.zeros(185, bool)
    classified[100:110] = True
    settings = Settings()
    assert turn_window(settings) == settings.classification.turn_window_keyframes == 20
    settings.frontend.keyframe_min_flow_px *= 2
    window = turn_window(settings)
    assert window == 10
    kfs = _keyframes(yaw, np.random.default_rng(5))
    scaled = turning_keyframes(kfs, window, 4.0, classified)
    assert scaled[128:173].all() and not scaled[:120].any() and not scaled[178:].any()  # measured: 123-176
    assert turning_keyframes(kfs, 20, 4.0, classified)[178:].all()  # measured: 130-184


def test_two_wrong_poses_in_a_straight_pipe_make_no_bend():
    """A straight pipe whose chained directions keep two relative poses turned 3 deg by mistake (320x240 H.264
    CCTV footage): the window over both turns 6 deg, past the threshold, but all of it in two steps."""
    yaw = np.zeros(120)
    yaw[50], yaw[56] = 3.0, 3.0
    kfs = _keyframes(yaw, np.random.default_rng(6))
    assert not turning_keyframes(kfs, 20, 4.0).any()
    # the same 6 deg spread over eight keyframes is a bend
    yaw = np.zeros(120)
    yaw[50:58] = 0.75
    assert turning_keyframes(_keyframes(yaw, np.random.default_rng(6)), 20, 4.0)[50:58].all()
