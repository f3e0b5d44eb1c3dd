"""frontend/settling.py: a track's observations in the keyframes just after it began are left out, the rest kept."""

from __future__ import annotations

import numpy as np

from pipemap.frontend.settling import SettlingFilter
from pipemap.frontend.tracks import Keyframe


def keyframe(number: int, ids) -> Keyframe:
    ids = np.asarray(ids, np.int64)
    n = len(ids)
    pts = np.column_stack([ids * 10.0, np.full(n, float(number))])
    bearings = np.tile([0.0, 0.0, 1.0], (n, 1))
    return Keyframe(number, number, float(number), pts, bearings, ids, np.arange(n) % 2 == 0, np.arange(n) % 3 == 0,
                    np.eye(3), np.zeros(3), number > 0)


def test_observations_one_and_two_after_a_track_began_are_left_out():
    # track 0..2 begin at keyframe 0; 3, 4 at keyframe 1; track 1 ends after keyframe 1; 5 begins at keyframe 3
    sequence = [[0, 1, 2], [0, 1, 2, 3, 4], [0, 2, 3, 4], [0, 2, 3, 4, 5], [0, 3, 5], [5]]
    settle = SettlingFilter(2)
    kept = [settle(keyframe(n, ids)).track_ids.tolist() for n, ids in enumerate(sequence)]
    assert kept == [[0, 1, 2], [3, 4], [], [0, 2, 5], [0, 3], []]
    assert settle.left_out == sum(map(len, sequence)) - sum(map(len, kept))


def test_the_rows_left_stay_together():
    settle = SettlingFilter(1)
    settle(keyframe(0, [0, 1]))
    full = keyframe(1, [0, 1, 2, 3])
    out = settle(full)
    keep = np.isin(full.track_ids, out.track_ids)
    assert out.track_ids.tolist() == [2, 3]
    for name in ("keypoints", "bearings", "inliers", "guided"):
        np.testing.assert_array_equal(getattr(out, name), getattr(full, name)[keep], err_msg=name)
    assert (out.R == full.R).all() and out.number == full.number and out.pose_valid == full.pose_valid


def test_none_left_out_at_zero():
    settle = SettlingFilter(0)
    for n in range(3):
        kf = keyframe(n, [0, 1, 2])
        assert settle(kf) is kf
    assert settle.left_out == 0


def test_the_settling_keyframes_cover_the_same_pictures_at_any_keyframe_spacing():
    """Two keyframes at the default spacing on H.264; one where keyframes come twice as far apart (two would leave
    out the observations 40 px of flow on, and fisheye-straight's reverse lost 44 %); none on a codec it does not
    apply to or on images."""
    from pipemap.config import Settings
    from pipemap.pipeline import settling_keyframes

    s = Settings()
    assert settling_keyframes(s, "h264") == s.frontend.predicted_settling_keyframes == 2
    assert settling_keyframes(s, "mpeg4") == settling_keyframes(s, None) == 0
    s.frontend.keyframe_min_flow_px = 20.0
    assert settling_keyframes(s, "h264") == 1
    s.frontend.keyframe_min_flow_px = 5.0
    assert settling_keyframes(s, "h264") == 4
    s.frontend.keyframe_min_flow_px = 0.0  # every frame a keyframe
    assert settling_keyframes(s, "h264") == 2


def test_the_settling_filter_is_for_a_camera_that_sees_the_wall_beside_it():
    """A forward CCTV camera sees each piece of wall over few keyframes and its scale rests on them: its H.264
    footage keeps every observation (cctv-recording's reverse leg 0.64 % off with the filter, 0.03 % without)."""
    from pipemap.config import Settings
    from pipemap.pipeline import settling_keyframes
    from pipemap.sim.presets import cctv_camera, fisheye_camera

    s = Settings()
    assert settling_keyframes(s, "h264", fisheye_camera(640, 480)) == 2
    assert settling_keyframes(s, "h264", cctv_camera(640, 480)) == 0
