"""The appearance map against the true wall: distances to a network's wall, and the global and
local figures of a synthetic result folder whose map lies on the wall under a known transform."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from rich.console import Console

from pipemap.errors import PipemapError
from pipemap.evaluation import evaluate, print_tables
from pipemap.evaluation import wall_error
from pipemap.evaluation.align import Alignment
from pipemap.evaluation.report import write_report
from pipemap.evaluation.wall_error import END_TOLERANCE_M, appearance_wall, wall_distance
from pipemap.geometry.rotations import exp_so3, look_rotation
from pipemap.mapping import write_appearance_ply
from pipemap.network import PipeNetwork, Segment, save_network
from pipemap.evaluation.metrics import ate
from pipemap.trajectory import Trajectory, read_tum, write_tum

R = 0.2
FPS = 7.5
CAMERA_DOWN_M = 0.04  # the crawler's camera rides below the pipe axis, as in the simulator
# An L of two straight pipes meeting at a tee, the first running on into a stub.
CORNER = np.array([2.0, 0.0, 0.0])
NETWORK = PipeNetwork(R, (Segment("S1", np.zeros(3), CORNER), Segment("S2", CORNER, np.array([2.0, 1.5, 0.0])),
                          Segment("B1", CORNER, np.array([2.4, 0.0, 0.0]))))
TRANSFORM = Alignment(exp_so3(np.array([0.3, -0.2, 1.1])), np.array([0.5, -1.0, 0.25]), 1.0)  # truth <- estimate


def _straight(start, end) -> PipeNetwork:
    return PipeNetwork(R, (Segment("S", np.asarray(start, float), np.asarray(end, float)),))


# -- wall_distance ----------------------------------------------------------------------------


def test_points_on_inside_and_outside_one_pipe():
    net = _straight([0, 0, 0], [1, 0, 0])
    pts = [[0.5, 0.2, 0.0], [0.3, 0.0, -0.2], [0.5, 0.15, 0.0], [0.5, 0.0, -0.23], [0.7, 0.0, 0.0],
           [0.5, 0.03, 0.04]]
    assert wall_distance(np.array(pts), net) == pytest.approx([0.0, 0.0, 0.05, 0.03, 0.2, 0.15], abs=1e-12)


def test_points_beyond_a_segment_end_measure_to_its_rim():
    net = _straight([0, 0, 0], [1, 0, 0])
    tol = END_TOLERANCE_M
    pts = [[1.0 + 0.8 * tol, 0.2, 0.0], [-0.8 * tol, 0.0, 0.21], [1.1, 0.2, 0.0], [1.1, 0.0, 0.25], [-0.3, 0.0, 0.0]]
    expected = [0.0, 0.01, 0.1 - tol, np.hypot(0.05, 0.1 - tol), np.hypot(0.2, 0.3 - tol)]
    assert wall_distance(np.array(pts), net) == pytest.approx(expected, abs=1e-12)


def test_near_a_kinked_joint_the_nearer_piece_counts():
    kink = np.radians(2.0)
    end = np.array([1.0 + np.cos(kink), np.sin(kink), 0.0])
    net = PipeNetwork(R, (Segment("a", np.zeros(3), np.array([1.0, 0, 0])), Segment("b", np.array([1.0, 0, 0]), end)))
    normal = np.array([-np.sin(kink), np.cos(kink), 0.0])  # across piece b, in the plane of the kink
    on_b = np.array([1.0, 0, 0]) + 0.05 * (end - [1.0, 0, 0]) + R * normal  # past a's end, on b's wall
    on_a = np.array([0.98, 0.0, -R])
    pushed = on_b + 0.003 * normal  # 3 mm outside b; a's rim lies farther
    d = wall_distance(np.stack([on_b, on_a, pushed]), net)
    assert d == pytest.approx([0.0, 0.0, 0.003], abs=1e-12)


def test_past_a_tee_the_through_pipe_and_the_branch_are_wall():
    # S1 runs on through the tee into the stub B1; S2 branches off along +y
    pts = [[2.05, -R, 0.0], [2.1, -R * np.cos(0.3), R * np.sin(0.3)], [2.0 - R, 0.7, 0.0], [2.3, 0.0, -0.15]]
    assert wall_distance(np.array(pts), NETWORK) == pytest.approx([0.0, 0.0, 0.0, 0.05], abs=1e-12)


def test_chunks_give_the_same_distances(monkeypatch):
    pts = np.random.default_rng(3).uniform([-0.5, -0.5, -0.5], [2.5, 2.0, 0.5], (1000, 3)).astype(np.float32)
    whole = wall_distance(pts, NETWORK)
    monkeypatch.setattr(wall_error, "CHUNK_POINTS", 37)
    assert np.array_equal(wall_distance(pts, NETWORK), whole)
    assert whole.shape == (1000,) and np.all(whole >= 0)


def test_a_long_network_measured_against_nearby_segments_first_is_exact(monkeypatch):
    """A chunk of points is measured against the segments near its own bounding box first (a 256 m loop has
    hundreds of pipe pieces): the same distances as against every segment, points far from all of them
    included, however the chunks fall."""
    rng = np.random.default_rng(5)
    corners = np.cumsum(rng.uniform(0.5, 3.0, (120, 3)) * [1, 1, 0.05], axis=0)
    net = PipeNetwork(R, tuple(Segment(f"S{i}", a, b) for i, (a, b) in enumerate(zip(corners, corners[1:]))))
    along = rng.integers(0, len(corners) - 1, 3000)
    f = rng.uniform(-0.1, 1.1, (3000, 1))
    pts = corners[along] + f * (corners[along + 1] - corners[along]) + rng.normal(0, 0.25, (3000, 3))
    pts = np.concatenate([pts, rng.uniform(-20, 200, (200, 3))])  # and some far from every pipe
    monkeypatch.setattr(wall_error, "CHUNK_POINTS", 100)
    prefiltered, near = wall_distance(pts, net), wall_error.NEAR_M
    monkeypatch.setattr(wall_error, "NEAR_M", np.inf)  # every segment a candidate
    np.testing.assert_array_equal(prefiltered, wall_distance(pts, net))
    assert np.sum(prefiltered > near) > 200  # the fallback was exercised


# -- a synthetic result folder ----------------------------------------------------------------


def _leg(start, end, n, t0):
    """Keyframes along a pipe axis, CAMERA_DOWN_M below it, looking forward: exactly collinear."""
    f = np.linspace(0.0, 1.0, n)[:, None]
    p = start + f * (end - start) + [0.0, 0.0, -CAMERA_DOWN_M]
    rot = look_rotation(np.broadcast_to(end - start, p.shape), np.array([0.0, 0.0, 1.0]))
    return Trajectory((t0 + np.arange(n)) / FPS, p, rot)


def _truth():
    legs = [_leg(np.array([0.2, 0, 0]), np.array([1.8, 0, 0]), 30, 0),
            _leg(np.array([2.0, 0.3, 0]), np.array([2.0, 1.3, 0]), 20, 30)]
    return Trajectory(*(np.concatenate([getattr(leg, k) for leg in legs])
                        for k in ("timestamps", "positions", "rotations")))


def _wall_points(rng, outwards_m=0.0):
    """Points on S1 and S2's walls (away from the tee), pushed `outwards_m` off the wall."""
    pts = []
    for seg, e1, e2 in ((NETWORK.segments[0], [0, 1, 0], [0, 0, 1]), (NETWORK.segments[1], [1, 0, 0], [0, 0, 1])):
        h = rng.uniform(0.3, seg.length - 0.3, 4000)
        phi = rng.uniform(0.0, 2 * np.pi, 4000)
        radial = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
        pts.append(seg.start + h[:, None] * seg.axis + (R + outwards_m) * radial)
    return np.concatenate(pts)


def _to_estimate(x: np.ndarray, transform: Alignment) -> np.ndarray:
    return (x - transform.translation) @ transform.rotation


def _result(root, points_truth, transform=TRANSFORM, second_leg=None):
    """trajectory.tum, appearance.ply and run.json in the estimate frame (truth = transform(estimate));
    the second leg and its wall may take a different transform (drift at the tee)."""
    second_leg = second_leg or transform
    gt = _truth()
    first = np.arange(len(gt)) < 30
    pos = np.where(first[:, None], _to_estimate(gt.positions, transform), _to_estimate(gt.positions, second_leg))
    rot = np.where(first[:, None, None], transform.rotation.T @ gt.rotations, second_leg.rotation.T @ gt.rotations)
    root.mkdir(parents=True)
    write_tum(root / "trajectory.tum", Trajectory(gt.timestamps, pos, rot))
    on_s1 = np.abs(points_truth[:, 0] - 2.0) > np.abs(points_truth[:, 1])
    pts = np.where(on_s1[:, None], _to_estimate(points_truth, transform), _to_estimate(points_truth, second_leg))
    write_appearance_ply(root / "appearance.ply", pts, np.full(len(pts), 128.0))
    pieces = [{"name": "S1", "start": _to_estimate(np.zeros(3), transform).tolist(),
               "end": _to_estimate(CORNER + [R, 0, 0], transform).tolist(), "radius": R},
              {"name": "S2", "start": _to_estimate(CORNER, second_leg).tolist(),
               "end": _to_estimate(np.array([2.0, 1.5, 0]), second_leg).tolist(), "radius": R}]
    sections = [{"section": 1, "first_keyframe": 0, "last_keyframe": 29},
                {"section": 2, "first_keyframe": 30, "last_keyframe": 49}]
    (root / "run.json").write_text(json.dumps({"straight_sections": sections, "wall_pieces": pieces}))
    return root


@pytest.fixture
def dataset(tmp_path):
    root = tmp_path / "data"
    (root / "ground_truth").mkdir(parents=True)
    (root / "dataset.yaml").write_text(yaml.safe_dump({"format": "pipemap-dataset/1", "name": "L"}))
    write_tum(root / "ground_truth" / "poses.tum", _truth())
    save_network(root / "ground_truth" / "network.yaml", NETWORK)
    return root


def _figure(result, transform=TRANSFORM):
    return appearance_wall(result, NETWORK, read_tum(result / "trajectory.tum"), _truth(), transform)


def test_a_map_on_the_true_wall_is_zero_millimetres_off(tmp_path):
    w = _figure(_result(tmp_path / "out", _wall_points(np.random.default_rng(0))))
    for s in (w.global_, w.local):
        assert s.points == 8000
        assert s.max_mm < 0.01 and s.within_2mm_pct == 100.0  # float32 coordinates: ~0.2 um
    assert [(p.piece, p.section, p.keyframes, p.stats.points) for p in w.pieces] == [("S1", 1, 30, 4000),
                                                                                       ("S2", 2, 20, 4000)]


def test_a_map_5_mm_outside_the_wall_is_5_mm_off(tmp_path):
    w = _figure(_result(tmp_path / "out", _wall_points(np.random.default_rng(1), outwards_m=0.005)))
    for s in (w.global_, w.local):
        assert s.median_mm == pytest.approx(5.0, abs=0.01) and s.p90_mm == pytest.approx(5.0, abs=0.01)
        assert s.max_mm == pytest.approx(5.0, abs=0.01) and s.within_2mm_pct == 0.0


def test_drift_at_the_tee_shows_globally_but_not_locally(tmp_path):
    # the second leg's estimate is turned by 1 deg about the tee: right locally, wrong in the whole
    turn = Alignment(exp_so3(np.radians([0.0, 0.0, 1.0])), np.zeros(3), 1.0)
    drifted = Alignment(TRANSFORM.rotation @ turn.rotation, TRANSFORM.translation + TRANSFORM.rotation @
                        (CORNER - turn.rotation @ CORNER), 1.0)
    result = _result(tmp_path / "out", _wall_points(np.random.default_rng(2)), second_leg=drifted)
    est, gt = read_tum(result / "trajectory.tum"), _truth()
    w = appearance_wall(result, NETWORK, est, gt, ate(est.positions, gt.positions).alignment)
    assert w.global_.max_mm > 5.0 and w.global_.within_2mm_pct < 90.0
    assert w.local.max_mm < 0.01


def test_collinear_keyframes_still_fix_the_roll_about_the_pipe(tmp_path):
    # a roll about S1's axis (the keyframes' line) that positions alone cannot see; the camera
    # rides 4 cm below the axis, so a wrong roll would move the wall by millimetres
    roll = exp_so3(np.array([0.7, 0.0, 0.0]))
    on_line = np.array([0.0, 0.0, -CAMERA_DOWN_M])
    transform = Alignment(roll, on_line - roll @ on_line, 1.0)
    w = _figure(_result(tmp_path / "out", _wall_points(np.random.default_rng(4)), transform), transform)
    assert w.pieces[0].stats.max_mm < 0.01 and w.local.max_mm < 0.01


def test_a_straight_run_is_aligned_globally_by_its_orientations_too(tmp_path):
    # A straight run's keyframes lie on one line: an alignment by positions may roll the map about it (here by
    # 0.5 rad, which the positions cannot see), and with the camera 4 cm below the pipe's axis that put a
    # straight pipe driven in and out 4.5 mm off the wall globally, 0.5 mm piece by piece
    result = _result(tmp_path / "out", _wall_points(np.random.default_rng(5)))
    straight = read_tum(result / "trajectory.tum").subset(np.arange(30))
    c0 = _truth().positions[0]
    roll = exp_so3(np.array([0.5, 0.0, 0.0]))
    wrong = Alignment(roll @ TRANSFORM.rotation, roll @ (TRANSFORM.translation - c0) + c0, 1.0)
    moved = straight.positions @ wrong.rotation.T + wrong.translation
    assert np.abs(moved - _truth().positions[:30]).max() < 1e-9  # the positions cannot tell
    w = appearance_wall(result, NETWORK, straight, _truth(), wrong)
    assert w.global_.max_mm < 0.01 and w.global_.within_2mm_pct == 100.0


# -- through `pipemap evaluate` ---------------------------------------------------------------


def test_evaluate_writes_prints_and_reports_the_figure(tmp_path, dataset):
    result = _result(tmp_path / "out", _wall_points(np.random.default_rng(5), outwards_m=0.005))
    res = evaluate(result, dataset)
    assert res.appearance_wall.global_.median_mm == pytest.approx(5.0, abs=0.01)
    metrics = json.loads((result / "metrics.json").read_text())
    assert metrics["appearance_wall"]["local"]["within_2mm_pct"] == 0.0
    assert [p["piece"] for p in metrics["appearance_wall"]["pieces"]] == ["S1", "S2"]
    console = Console(record=True, width=120)
    print_tables(res, console)
    text = console.export_text()
    assert "Appearance map vs true wall" in text and "5.00" in text
    html = write_report(result, dataset).read_text()
    assert "Appearance map vs true wall" in html and "<td class=n>5.00</td>" in html


def test_a_result_without_appearance_ply_has_no_figure_and_says_why(tmp_path, dataset):
    result = _result(tmp_path / "out", _wall_points(np.random.default_rng(6)))
    (result / "appearance.ply").unlink()
    res = evaluate(result, dataset)
    assert res.appearance_wall is None and any("appearance.ply" in n for n in res.notes)
    assert json.loads((result / "metrics.json").read_text())["appearance_wall"] is None


def test_pieces_without_a_section_are_left_out_with_a_note(tmp_path, dataset):
    result = _result(tmp_path / "out", _wall_points(np.random.default_rng(7)))
    run = json.loads((result / "run.json").read_text())
    run["straight_sections"] = run["straight_sections"][:1]
    (result / "run.json").write_text(json.dumps(run))
    res = evaluate(result, dataset)
    assert [p.piece for p in res.appearance_wall.pieces] == ["S1"] and res.appearance_wall.local.points == 4000
    assert any("S2" in n for n in res.notes)


def test_without_run_json_only_the_global_figure_is_given(tmp_path, dataset):
    result = _result(tmp_path / "out", _wall_points(np.random.default_rng(9)))
    (result / "run.json").unlink()
    res = evaluate(result, dataset)
    assert res.appearance_wall.global_.max_mm < 0.01 and res.appearance_wall.local is None
    assert any("run.json" in n for n in res.notes)


def test_an_empty_map_has_no_distances(tmp_path, dataset):
    result = _result(tmp_path / "out", np.zeros((0, 3)))
    res = evaluate(result, dataset)
    assert res.appearance_wall.global_.points == res.appearance_wall.local.points == 0
    assert json.loads((result / "metrics.json").read_text())["appearance_wall"]["global"]["median_mm"] is None


@pytest.mark.parametrize("damage", ["garbage", "truncated", "no x"])
def test_a_corrupt_ply_is_one_error_naming_the_file(tmp_path, dataset, damage):
    result = _result(tmp_path / "out", _wall_points(np.random.default_rng(8)))
    ply = result / "appearance.ply"
    if damage == "garbage":
        ply.write_bytes(b"this is not a ply file\n" * 4)
    elif damage == "truncated":
        ply.write_bytes(ply.read_bytes()[:-1000])
    else:
        ply.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float u\nend_header\n0.5\n")
    with pytest.raises(PipemapError) as err:
        evaluate(result, dataset)
    assert str(ply) in str(err.value)
    assert not (result / "metrics.json").exists()
