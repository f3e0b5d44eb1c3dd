"""Keyframe rule, the keyframe trajectory, and the tracks/frames files."""

import numpy as np
import pytest

from pipemap.errors import PipemapError
from pipemap.frontend import Keyframe, chain_poses, needs_keyframe, read_tracks_csv, track_lengths, write_tracks_csv
from pipemap.frontend.tracks_io import read_frames_csv, write_frames_csv
from pipemap.geometry.rotations import exp_so3


def keyframe(number, R=np.eye(3), t=np.zeros(3), ids=(0, 1), valid=True):
    n = len(ids)
    return Keyframe(number, 2 * number, 0.2 * number, np.arange(2 * n, dtype=float).reshape(n, 2) + number,
                    np.tile([0.0, 0.0, 1.0], (n, 1)), np.array(ids, np.int64), np.ones(n, bool), np.zeros(n, bool),
                    R, t, valid)


def test_keyframe_rule():
    assert needs_keyframe(12.0, 0.9, 10.0, 0.5)
    assert needs_keyframe(3.0, 0.4, 10.0, 0.5)
    assert not needs_keyframe(3.0, 0.9, 10.0, 0.5)


def test_chained_poses_reproduce_a_known_path():
    rng = np.random.default_rng(0)
    R_wc = [np.eye(3)]
    c = [np.zeros(3)]
    kfs = [keyframe(0, valid=False)]
    for k in range(1, 6):
        R_wc.append(R_wc[-1] @ exp_so3(rng.normal(scale=0.1, size=3)))
        step = rng.normal(size=3)
        c.append(c[-1] + step / np.linalg.norm(step))
        # X_k = R X_{k-1} + t from the two camera poses.
        R = R_wc[k].T @ R_wc[k - 1]
        t = R_wc[k].T @ (c[k - 1] - c[k])
        kfs.append(keyframe(k, R, t))
    traj = chain_poses(kfs)
    assert np.allclose(traj.positions, np.array(c), atol=1e-12)
    assert np.allclose(traj.rotations, np.array(R_wc), atol=1e-12)
    assert np.allclose(traj.timestamps, [0.2 * k for k in range(6)])


def test_a_lost_step_continues_in_the_last_direction():
    t = np.array([0.0, 0.0, -1.0])
    traj = chain_poses([keyframe(0, valid=False), keyframe(1, np.eye(3), t), keyframe(2, valid=False)])
    assert np.allclose(traj.positions[2] - traj.positions[1], traj.positions[1] - traj.positions[0])


def test_tracks_file_round_trip_and_lengths(tmp_path):
    kfs = [keyframe(0, ids=(0, 1)), keyframe(1, ids=(1, 2, 3)), keyframe(2, ids=(1, 3))]
    write_tracks_csv(tmp_path / "tracks.csv", kfs)
    data = read_tracks_csv(tmp_path / "tracks.csv")
    assert list(data["track_id"]) == [0, 1, 1, 2, 3, 1, 3]
    assert list(data["keyframe"]) == [0, 0, 1, 1, 1, 2, 2]
    assert np.allclose(data["u"][:2], kfs[0].keypoints[:, 0], atol=1e-3)
    assert track_lengths(kfs) == {0: 1, 1: 3, 2: 1, 3: 2}
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    with pytest.raises(PipemapError, match="header"):
        read_tracks_csv(tmp_path / "bad.csv")
    with pytest.raises(PipemapError, match="not found"):
        read_tracks_csv(tmp_path / "missing.csv")


def test_frames_file(tmp_path):
    write_frames_csv(tmp_path / "frames.csv", 5, [0, 3])
    assert (tmp_path / "frames.csv").read_text().splitlines()[:2] == ["index,keyframe,label", "0,1,straight"]
    data = read_frames_csv(tmp_path / "frames.csv")
    assert list(data["keyframe"]) == [True, False, False, True, False]
