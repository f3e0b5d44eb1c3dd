"""benchmarks/bench_exact_observations.py: the true wall point behind a ray, in a tee's union of pipes, and the
parts of the tracking's error it hands the back end."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pipemap.geometry.rotations import exp_so3
from pipemap.sim.presets import fisheye_camera

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_exact_observations.py"
_SPEC = importlib.util.spec_from_file_location("bench_exact_observations", _PATH)
bench = importlib.util.module_from_spec(_SPEC)
sys.modules[_SPEC.name] = bench
_SPEC.loader.exec_module(bench)
R = 0.15


def pipe(start, end):
    start, end = np.asarray(start, float), np.asarray(end, float)
    return SimpleNamespace(start=start, axis=(end - start) / np.linalg.norm(end - start),
                           length=float(np.linalg.norm(end - start)))


TEE = [pipe([0, 0, 0], [4, 0, 0]), pipe([2, 0, 0], [2, 1, 0])]  # a run along x, a branch along +y at x = 2


def test_a_ray_to_the_wall_meets_it_at_the_radius():
    origin = np.array([0.5, 0.0, -0.04])
    ray = np.array([0.6, 0.0, -0.8])
    p = bench.wall_points(TEE, R, origin, ray)[0]
    assert np.hypot(p[1], p[2]) == pytest.approx(R, abs=1e-12)
    assert np.cross(p - origin, ray) == pytest.approx(np.zeros(3), abs=1e-12)


def test_a_ray_into_the_side_opening_meets_the_branch_wall():
    origin = np.array([1.9, 0.0, 0.0])
    ray = np.array([0.5, 0.5, 0.0])
    ray /= np.linalg.norm(ray)
    p = bench.wall_points(TEE, R, origin, ray)[0]
    assert p[1] > R  # past where the run's own wall would be: through its opening
    assert np.hypot(p[0] - 2.0, p[2]) == pytest.approx(R, abs=1e-12)


def test_a_ray_past_the_pipes_meets_no_wall():
    assert np.isnan(bench.wall_points(TEE, R, np.array([3.9, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]))).all()


def test_rays_at_once_give_what_each_gives_alone():
    rng = np.random.default_rng(3)
    rays = rng.normal(size=(50, 3))
    origin = np.array([1.9, 0.02, -0.03])
    together = bench.wall_points(TEE, R, origin, rays)
    alone = np.concatenate([bench.wall_points(TEE, R, origin, r) for r in rays])
    np.testing.assert_allclose(together, alone, rtol=0, atol=1e-12)  # the same sums, maybe in another order
    assert np.isfinite(together).all(axis=1).sum() > 40


def test_a_ray_says_which_pipe_it_met():
    origin = np.array([1.9, 0.0, 0.0])
    rays = np.array([[0.6, 0.0, -0.8], [0.5, 0.5, 0.0], [1.0, 0.0, 0.0]])
    rays /= np.linalg.norm(rays, axis=1)[:, None]
    points, met = bench.wall_points(TEE, R, origin, rays, which=True)
    assert met.tolist() == [0, 1, -1]  # the run's wall, the branch's through its opening, none down the run's end
    np.testing.assert_array_equal(points, bench.wall_points(TEE, R, origin, rays))


def test_a_part_on_chosen_pipes_leaves_the_other_tracks_exact():
    exact = np.array([[100.0, 100.0], [300.0, 400.0]])
    tracked = np.array([[100.3, 100.4], [299.0, 401.0]])
    motion = np.array([[1.0, 0.0], [0.0, 1.0]])
    got = bench.part_pixels("across", tracked, exact, motion, np.array([1, 4]), 240.0, on=np.array([False, True]))
    np.testing.assert_allclose(got, [[100.0, 100.0], [299.0, 400.0]], atol=1e-12)


def test_parts_hand_over_exact_pixels_plus_the_error_asked_for():
    exact = np.array([[100.0, 100.0], [300.0, 400.0], [np.nan, np.nan]])
    tracked = np.array([[100.3, 100.4], [299.0, 401.0], [50.0, 60.0]])
    motion = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    place = np.array([1, 4, 0])
    got = {p: bench.part_pixels(p, tracked, exact, motion, place, 240.0, np.array([40.0, 87.0, 10.0]))
           for p in bench.PIXEL_PARTS}
    expected = {"all": tracked[:2], "exact": exact[:2], "along": [[100.3, 100.0], [300.0, 401.0]],
                "across": [[100.0, 100.4], [299.0, 400.0]], "top": [tracked[0], exact[1]],
                "bottom": [exact[0], tracked[1]], "early": [tracked[0], exact[1]], "late": [exact[0], tracked[1]],
                "inner": [tracked[0], exact[1]], "rim": [exact[0], tracked[1]],
                "early-along": [[100.3, 100.0], exact[1]], "early-across": [[100.0, 100.4], exact[1]],
                "late-along": [exact[0], [300.0, 401.0]], "late-across": [exact[0], [299.0, 400.0]],
                "inner-along": [[100.3, 100.0], exact[1]], "rim-along": [exact[0], [300.0, 401.0]]}
    for p in bench.PIXEL_PARTS:
        np.testing.assert_allclose(got[p][:2], expected[p], atol=1e-12, err_msg=p)
        np.testing.assert_allclose(got[p][2], tracked[2], err_msg=p)  # no exact projection: the tracked one stays


def test_errors_by_place_split_along_and_across_the_motion():
    # motion +u: across is the motion turned +90 deg (image y down), +v; motion +v: across is -u.
    # Colatitudes on this lens: 20, 40, 24 and 56 deg.
    exact = np.array([[370.0, 240.0], [420.0, 240.0], [320.0, 300.0], [320.0, 100.0]])
    tracked = exact + [[0.1, 0.2], [0.3, -0.2], [0.4, 0.1], [9.0, 9.0]]  # the last is past the 2 px cut
    motion = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    front = SimpleNamespace(keyframes=[SimpleNamespace(keypoints=tracked)])
    got = bench.errors_by_place_and_sector(front, fisheye_camera(640, 480), [exact], [motion],
                                           [np.array([1, 1, 3, 1])])
    assert got["observations_by_place"] == {1: 2, 3: 1}
    np.testing.assert_allclose([got["along_motion_px_by_place"][1], got["along_motion_px_by_place"][3]], [0.2, 0.1])
    np.testing.assert_allclose([got["across_motion_px_by_place"][1], got["across_motion_px_by_place"][3]], [0.0, -0.4])
    np.testing.assert_allclose(got["along_rms_px_by_place"][1], np.sqrt((0.01 + 0.09) / 2))
    np.testing.assert_allclose(got["across_median_abs_px_by_place"][1], 0.2)
    np.testing.assert_allclose(got["along_motion_px_by_sector"]["+0..+45"], 0.2)  # both right of the centre
    by_colatitude = got["along_motion_px_by_colatitude"]
    assert sorted(by_colatitude) == ["0..30", "30..45"]
    assert sorted(by_colatitude["0..30"]) == ["1-2", "3-4"]
    np.testing.assert_allclose([by_colatitude["0..30"]["1-2"][0], by_colatitude["0..30"]["3-4"][0],
                                by_colatitude["30..45"]["1-2"][0]], [0.1, 0.1, 0.3])
    assert [by_colatitude["0..30"]["1-2"][1], by_colatitude["30..45"]["1-2"][1]] == [1, 1]


def test_the_mean_lag_of_a_place_in_the_track_is_taken_along_each_motion():
    # Two observations at place 1 lag by 0.1 and 0.3 px along their motions, one at place 2 leads by 0.2.
    exact = [np.array([[100.0, 100.0], [200.0, 100.0]]), np.array([[110.0, 100.0], [200.0, 90.0], [50.0, 50.0]])]
    motions = [np.zeros((2, 2)), np.array([[1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])]
    places = [np.array([0, 0]), np.array([1, 1, 2])]
    keypoints = [exact[0], exact[1] + [[-0.1, 0.0], [0.0, 0.3], [0.0, 0.2]]]
    front = SimpleNamespace(keyframes=[SimpleNamespace(keypoints=k) for k in keypoints])
    lags = bench.mean_lag(front, fisheye_camera(640, 480), exact, motions, places, "")
    np.testing.assert_allclose(lags[0], 0.0)
    np.testing.assert_allclose(lags[1], [[-0.2, 0.0], [0.0, 0.2], [0.0, 0.2]], atol=1e-12)


def test_noise_is_added_to_exact_pixels_only():
    exact = [np.array([[100.0, 100.0], [np.nan, np.nan]])]
    tracked = [SimpleNamespace(keypoints=np.array([[100.5, 99.5], [7.0, 8.0]]))]
    got = bench.noisy(tracked, exact, 0.3, np.random.default_rng(1))[0]
    np.testing.assert_array_equal(got[1], [7.0, 8.0])
    draws = np.array([bench.noisy(tracked, exact, 0.3, np.random.default_rng(s))[0][0] for s in range(2000)])
    np.testing.assert_allclose(draws.mean(axis=0), [100.0, 100.0], atol=0.03)
    np.testing.assert_allclose(draws.std(axis=0), [0.3, 0.3], rtol=0.05)


def test_errors_by_turn_group_keyframes_by_their_true_rotation():
    def about_z(deg):
        a = np.radians(deg)
        return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    R = np.array([about_z(0.0), about_z(0.2), about_z(5.2)])  # turns of 0.2 and 5 deg from the keyframe before
    exact = [np.array([[100.0, 100.0]])] * 3
    motions = [np.array([[1.0, 0.0]])] * 3
    places = [np.array([0]), np.array([1]), np.array([2])]
    front = SimpleNamespace(keyframes=[SimpleNamespace(keypoints=exact[0] + [[e, 0.3]]) for e in (0.0, -0.05, -0.1)])
    got = bench.errors_by_turn(front, exact, motions, places, R)
    assert sorted(got) == ["0..0.5", "4..6"]
    assert got["0..0.5"]["keyframes"] == 2 and got["4..6"]["keyframes"] == 1
    assert got["0..0.5"][1] == pytest.approx((-0.05, 1)) and got["4..6"][2] == pytest.approx((-0.1, 1))


def test_a_picture_whose_young_observations_sit_off_as_a_whole_gives_that_rotation():
    def about(axis, deg):
        return exp_so3(np.radians(deg) * np.asarray(axis, float) / np.linalg.norm(axis))
    camera = fisheye_camera(640, 480)
    rng = np.random.default_rng(3)
    exact = np.column_stack([rng.uniform(80, 560, 60), rng.uniform(60, 420, 60)])  # some beyond the lens's circle
    rays, _ = camera.unproject(exact)
    offset = about([0.3, -1.0, 0.2], 0.15)  # the decoded picture's content turned by 0.15 deg
    tracked, _ = camera.project(rays.reshape(-1, 3) @ offset.T)
    R = np.array([np.eye(3), about([0, 1, 0], 5.0)])  # the keyframe turned 5 deg from the one before
    front = SimpleNamespace(keyframes=[SimpleNamespace(keypoints=exact), SimpleNamespace(keypoints=tracked)])
    got = bench.frame_rotations(front, camera, [exact, exact], [np.zeros(60, int), np.ones(60, int)], R)
    expected = np.degrees(np.radians(0.15) * np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2]))
    assert got["4..180"]["keyframes"] == 1
    np.testing.assert_allclose(got["4..180"]["mean_deg"], expected, atol=2e-4)
    assert got["turns"][0]["keyframes"] == [1, 1] and got["turns"][0]["true_turn_deg"] == pytest.approx(5.0, abs=0.01)


def test_the_keyframes_near_a_turn_are_those_within_reach_of_a_turning_one():
    def about_z(deg):
        a = np.radians(deg)
        return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    headings = [0.0, 0.1, 0.2, 0.3, 0.4, 3.4, 6.4, 6.5, 6.6, 6.7, 6.8, 6.9]  # keyframes 5 and 6 turn 3 deg each
    near = bench.near_turns(np.array([about_z(h) for h in headings]), 2)
    np.testing.assert_array_equal(np.flatnonzero(near), [3, 4, 5, 6, 7, 8])
    assert not bench.near_turns(np.array([about_z(0.1 * k) for k in range(5)]), 2).any()
    # a sweeping bend turns 0.3 deg a keyframe (keyframes 3-5): a turn at 0.2 deg, none at the default 2 deg
    sweep = np.array([about_z(h) for h in [0.0, 0.05, 0.1, 0.4, 0.7, 1.0, 1.05, 1.1]])
    np.testing.assert_array_equal(np.flatnonzero(bench.near_turns(sweep, 0, turn_deg=0.2)), [3, 4, 5])
    assert not bench.near_turns(sweep, 0).any()
