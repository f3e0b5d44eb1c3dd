"""The camera's offset measured at stations along a dense run (straight/stations.py): where the stations go,
how the offset is interpolated, and each station's offset against the simulator's truth on the oblique render."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipemap.dataset import load_dataset
from pipemap.straight.sparse.batch import mount_of
from pipemap.straight.stations import OffsetTrack, consistent, station_starts

TO_PIPE = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # simulator world (x along, z up) -> (X, Y, h)


def test_stations_every_so_many_metres_of_travel_forward_and_back():
    """1 m forward then 0.5 m back in 10 mm steps, stations every 0.3 m of travel: at 0.3, 0.6, 0.9, 1.2 (0.2 m
    back) and 1.5 m of travel, never at the first frame."""
    along = np.r_[np.arange(0, 1.0001, 0.01), np.arange(0.99, 0.4999, -0.01)]
    indices = np.arange(len(along)) * 2  # every second image registered
    starts = station_starts(indices, along, 0.3)
    assert starts == [60, 120, 180, 240] or starts == [60, 120, 180, 240, 300]
    travel = np.r_[0, np.cumsum(np.abs(np.diff(along)))]
    for s, mark in zip(starts, (0.3, 0.6, 0.9, 1.2)):
        assert travel[s // 2] == pytest.approx(mark, abs=0.0101)
    assert station_starts(indices, along, 0.0) == []


def test_offset_between_stations_is_linear_and_held_beyond_them():
    track = OffsetTrack(np.array([10.0, 30.0]), np.array([[-0.03, -0.04], [-0.02, -0.042]]), np.full(2, 1e-4),
                        np.array([[0, 20], [20, 40]]), np.tile([0.97, 0.0, 0.26], (2, 1)))
    at = track.at([0, 10, 20, 30, 99])
    assert np.allclose(at[:, 0], [-0.03, -0.03, -0.025, -0.02, -0.02])
    assert np.allclose(at[:, 1], [-0.04, -0.04, -0.041, -0.042, -0.042])


def test_a_station_far_from_the_others_is_left_out():
    """The robot rides +-2.5 mm; one station 10 mm off (a short batch gone wrong) and one with C_X on the wrong side
    are left out, the run's own mount (the first) never, and a station off by its own large sigma is kept."""
    rng = np.random.default_rng(0)
    offsets = np.column_stack([-0.030 + 0.001 * rng.standard_normal(20), -0.040 + 0.0015 * np.sin(np.arange(20))])
    sigmas = np.full(20, 2e-4)
    offsets[7, 1] += 0.010
    offsets[12, 0] = 0.029
    offsets[15, 1] += 0.006
    sigmas[15] = 0.002
    keep = consistent(offsets, sigmas)
    assert not keep[7] and not keep[12] and keep[15] and keep.sum() == 18
    offsets[0, 1] += 0.02
    assert consistent(offsets, sigmas)[0]
    assert consistent(offsets[:3], sigmas[:3]).all()  # too few to judge


def test_each_station_measures_the_offset_where_it_is(oblique_wall, oblique_dense):
    """On the oblique render (the robot riding 3 mm up and down over 1 m, 480x360), every station's C_X within
    0.3 mm and C_Y within three of its sigmas (0.15-0.4 mm from a batch of 10 keyframes) of the truth averaged over
    its own keyframes: the stations follow the robot, not the
    start of the run. They are spread along the run, one about every dense.offset_station_m."""
    out, res = oblique_dense
    run = json.loads((out / "run.json").read_text())
    stations = run["scale"]["offset_along_run"]["stations"]
    gt = load_dataset(oblique_wall).ground_truth_poses()
    travel = abs(gt.positions[-1, 0] - gt.positions[0, 0])
    assert len(stations) >= int(travel / 0.3)
    errors = []
    for st in stations:
        a, b = st["keyframes"]
        truth = np.mean([mount_of(TO_PIPE @ gt.rotations[i], gt.positions[i] @ TO_PIPE.T) for i in range(a, b + 1)],
                        axis=0)
        err = np.array([st["C_X_m"] - truth[2], st["C_Y_m"] - truth[3]])
        errors.append(err)
        assert abs(err[0]) < 3e-4 and abs(err[1]) < 3 * st["C_Y_sigma_m"] + 5e-5, (st, truth)


def test_the_view_turns_to_the_stations_mean_axis_only_when_it_changes_the_scale():
    """The stations' pipe axes average to the run's. A view whose registered band is centred 0.34 f off its
    principal point (a 75 deg mount) is turned to a mean 0.2 deg off the first frames' mount (2 delta tan(theta):
    0.24 %), not to one 0.01 deg off (0.012 %, under dense.rerectify_min_pct 0.02); a view centred on
    its principal point (square to the wall) never."""
    from types import SimpleNamespace

    from pipemap.straight.dense import _mean_turn
    from pipemap.straight.sparse.geometry import rotation_from_travel

    def axis(angle_deg):
        a = np.radians(angle_deg)
        return np.array([np.sin(a), 0.0, np.cos(a)])

    def view(centre_px):
        K = np.array([[300.0, 0, centre_px], [0, 300.0, 100.0], [0, 0, 1]])
        rect = SimpleNamespace(K=K, size=(301, 200), focal_px=300.0)
        return SimpleNamespace(turn=rotation_from_travel(axis(75.0)), rect=rect)

    for spread, centred, expect in ((0.2, 48.0, True), (0.01, 48.0, False), (0.2, 150.0, False)):
        axes = np.array([axis(75.0), axis(75.0 + 2 * spread), axis(75.0 + spread), axis(75.0 + spread)])
        track = OffsetTrack(np.arange(4.0), np.zeros((4, 2)), np.full(4, 1e-4), np.zeros((4, 2), int), axes)
        turn = _mean_turn(view(centred), track, 0.02)
        assert (turn is not None) == expect, (spread, centred)
        if expect:
            assert np.degrees(np.arccos(turn[2][2])) == pytest.approx(75.0 + spread, abs=1e-3)
            np.testing.assert_allclose(turn @ turn.T, np.eye(3), atol=1e-12)
