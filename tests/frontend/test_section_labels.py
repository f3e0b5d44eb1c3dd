"""Keyframe classes decided while tracking runs (section_labels.py) against those of the whole sequence."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipemap.frontend.classification import temporal_filter
from pipemap.frontend.section_labels import KeyframeClasses
from pipemap.frontend.tracks import Keyframe
from pipemap.frontend.turning import turning_keyframes


def _sequence(seed: int, frames: int = 900):
    """Raw image classes: straight runs of 1-150 frames and junction runs of 1-25 (flicker among them),
    keyframes every 1-4 frames turning about 0.05 deg each and through bends of 0.5 deg per keyframe,
    tracking lost now and then."""
    rng = np.random.default_rng(seed)
    runs = [np.full(rng.integers(1, 150 if j == 0 else 25), bool(j)) for _ in range(frames // 10) for j in (0, 1)]
    raw = np.concatenate(runs)[:frames]
    index = np.cumsum(rng.integers(1, 5, frames))
    index = index[index < frames]
    bend = np.zeros(len(index))
    for start in rng.integers(0, len(index), 10):
        bend[start:start + 40] = 0.5
    keyframes = []
    for k, i in enumerate(index.tolist()):
        lost = k == 0 or rng.random() < 0.01
        rotvec = np.radians(np.r_[rng.normal(0, 0.05, 2), 0.0] + [0.0, bend[k], 0.0])
        R = np.eye(3) if lost else Rotation.from_rotvec(rotvec).as_matrix()
        keyframes.append(Keyframe(k, i, i / 7.5, np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, np.int64),
                                  np.zeros(0, bool), np.zeros(0, bool), R, np.zeros(3), not lost))
    return raw, keyframes


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_classes_handed_out_while_tracking_are_those_of_the_whole_sequence(seed):
    min_cluster, turn_deg, window = 5, 4.0, 20
    raw, keyframes = _sequence(seed)
    filtered = temporal_filter(raw, min_cluster)
    junction = filtered[[kf.index for kf in keyframes]]
    bends = turning_keyframes(keyframes, window, turn_deg, junction) & ~junction
    assert bends.any() and junction.any() and not junction.all()
    want = junction | bends

    rng = np.random.default_rng(seed + 10)
    classes = KeyframeClasses(min_cluster, turn_deg, window)
    got, lags = [], []
    n_frames = n_kf = 0
    while n_frames < len(raw):
        n_frames = min(len(raw), n_frames + int(rng.integers(1, 6)))
        while n_kf < len(keyframes) and keyframes[n_kf].index < n_frames:
            n_kf += 1
        out = classes.update(keyframes[:n_kf], list(range(len(raw))), list(raw[:n_frames]))
        got += out
        lags.append(n_kf - len(got))
    got += classes.update(keyframes, list(range(len(raw))), list(raw), done=True)
    assert [k for k, _ in got] == list(range(len(keyframes)))
    np.testing.assert_array_equal([j for _, j in got], want)
    np.testing.assert_array_equal(classes.bends, bends)
    # the classes follow the tracking by the turn test's reach (two windows), however long a section runs
    assert max(lags) <= 2 * window + 10
