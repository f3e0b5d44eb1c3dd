import json

import numpy as np
import pytest
import yaml
from rich.console import Console

from pipemap.errors import PipemapError
from pipemap.evaluation import associate, evaluate, junction_table, print_tables, tables
from pipemap.evaluation.metrics import route_pairs
from pipemap.geometry.rotations import exp_so3, look_rotation
from pipemap.network import Junction, PipeNetwork, Segment, save_network
from pipemap.trajectory import Trajectory, write_tum

FPS = 7.5
CORNERS = {  # a slightly irregular loop, like the fisheye paper's four T-intersections
    "T1": np.array([0.0, 0.0, 0.0]),
    "T2": np.array([8.15, 0.0, 0.02]),
    "T3": np.array([8.10, 8.17, 0.0]),
    "T4": np.array([-0.05, 8.12, -0.03]),
}


def _route_trajectory(waypoints, per_leg=40):
    """Camera poses along a polyline, looking forward, with a small wobble off the axis."""
    pts = []
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        f = np.linspace(0.0, 1.0, per_leg, endpoint=False)[:, None]
        pts.append(a + f * (b - a))
    pts.append(waypoints[-1][None])
    p = np.concatenate(pts)
    n = len(p)
    p = p + 0.03 * np.stack([np.sin(np.arange(n) * 0.7), np.cos(np.arange(n) * 0.3), np.sin(np.arange(n) * 0.5)], 1)
    forward = np.gradient(p, axis=0)
    return Trajectory(np.arange(n) / FPS, p, look_rotation(forward, np.array([0.0, 0.0, 1.0])))


def _dataset(root, network, gt, name="synthetic"):
    (root / "ground_truth").mkdir(parents=True)
    (root / "dataset.yaml").write_text(yaml.safe_dump({"format": "pipemap-dataset/1", "name": name}))
    write_tum(root / "ground_truth" / "poses.tum", gt)
    save_network(root / "ground_truth" / "network.yaml", network)
    return root


def _result(root, est, junctions=None):
    root.mkdir(parents=True)
    write_tum(root / "trajectory.tum", est)
    if junctions is not None:
        items = [{"id": j, "type": "tee", "centroid": [float(v) for v in c], "keyframe": i}
                 for i, (j, c) in enumerate(junctions)]
        (root / "junctions.yaml").write_text(yaml.safe_dump({"format": "pipemap-junctions/1", "junctions": items}))
    return root


def _loop(tmp_path, route=("T1", "T2", "T3", "T4", "T1")):
    ids = list(CORNERS)
    segments = tuple(Segment(f"S{i}", CORNERS[a], CORNERS[b]) for i, (a, b) in enumerate(zip(ids, ids[1:] + ids[:1])))
    network = PipeNetwork(0.2, segments, tuple(Junction(j, "tee", c) for j, c in CORNERS.items()), tuple(route))
    gt = _route_trajectory([CORNERS[j] for j in route])
    return _dataset(tmp_path / "data", network, gt), gt


def _transformed(traj, R=np.eye(3), t=np.zeros(3), s=1.0, keep=slice(None)):
    sub = traj.subset(keep)
    return Trajectory(sub.timestamps, s * sub.positions @ R.T + t, R @ sub.rotations)


def _true_junctions(route, R=np.eye(3), t=np.zeros(3), s=1.0):
    return [(f"J{i}", s * R @ CORNERS[j] + t) for i, j in enumerate(dict.fromkeys(route))]


def test_ground_truth_as_estimate_has_zero_error_and_writes_metrics(tmp_path):
    data, gt = _loop(tmp_path)
    res = evaluate(_result(tmp_path / "out", gt, _true_junctions(("T1", "T2", "T3", "T4"))), data)
    assert res.estimated_poses == res.associated_poses == res.ground_truth_poses == len(gt)
    assert res.ate_rigid.rmse < 1e-9 and res.ate_rigid.max < 1e-9
    assert res.ate_sim3.rmse < 1e-9 and res.ate_sim3.scale == pytest.approx(1.0, abs=1e-9)
    assert abs(res.path_length_error) < 1e-9
    assert res.distance is None  # four segments: not a straight run
    assert len(res.junctions.pairs) == 6
    assert all(abs(p.error) < 1e-9 and abs(p.error_pct) < 1e-7 for p in res.junctions.pairs)
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert list(metrics) == ["format", "dataset", "poses", "ate", "path_length", "distance_travelled", "junctions",
                             "sections", "appearance_wall", "notes"]
    assert metrics["format"] == "pipemap-metrics/1" and metrics["dataset"] == "synthetic"
    assert metrics["poses"]["associated"] == len(gt)
    assert set(metrics["ate"]) == {"rigid", "sim3"}
    assert metrics["ate"]["rigid"]["rmse_m"] < 1e-9 and metrics["distance_travelled"] is None
    assert [p["truth_ids"] for p in metrics["junctions"]["pairs"]] == [
        ["T1", "T2"], ["T2", "T3"], ["T3", "T4"], ["T4", "T1"], ["T1", "T3"], ["T2", "T4"]]  # Table I's columns
    assert [f.name for f in (tmp_path / "out").iterdir() if f.name.startswith(".")] == []  # no temp file left


def test_copy_scaled_by_1_01_has_one_percent_errors(tmp_path):
    data, gt = _loop(tmp_path)
    centre = np.array([3.0, -2.0, 1.0])
    est = _transformed(gt, s=1.01, t=(1 - 1.01) * centre)  # positions x1.01 about `centre`
    junctions = _true_junctions(("T1", "T2", "T3", "T4"), s=1.01, t=(1 - 1.01) * centre)
    res = evaluate(_result(tmp_path / "out", est, junctions), data)
    assert res.path_length_error_pct == pytest.approx(1.0, abs=1e-6)
    assert all(p.error_pct == pytest.approx(1.0, abs=1e-6) for p in res.junctions.pairs)
    assert res.junctions.max_abs_error_pct == pytest.approx(1.0, abs=1e-6)
    # The Sim(3) scale maps the estimate onto ground truth: 1/1.01 for an estimate 1 % too large.
    assert res.ate_sim3.rmse < 1e-8 and res.ate_sim3.scale == pytest.approx(1 / 1.01, abs=1e-9)
    assert res.ate_rigid.rmse > 1e-3 and res.ate_rigid.scale == 1.0


def test_rigidly_moved_copy_has_zero_rigid_ate(tmp_path):
    data, gt = _loop(tmp_path)
    R, t = exp_so3(np.array([0.3, -1.2, 2.0])), np.array([10.0, -4.0, 2.5])
    res = evaluate(_result(tmp_path / "out", _transformed(gt, R, t),
                           _true_junctions(("T1", "T2", "T3", "T4"), R, t)), data)
    assert res.ate_rigid.rmse < 1e-8
    np.testing.assert_allclose(res.ate_rigid.alignment.rotation, R.T, atol=1e-8)
    assert all(abs(p.error) < 1e-8 for p in res.junctions.pairs)


def test_keyframe_subset_associates_by_timestamp(tmp_path):
    data, gt = _loop(tmp_path)
    kf = _transformed(gt, keep=slice(0, None, 3))
    stray = Trajectory(np.array([1000.0]), np.zeros((1, 3)), np.eye(3)[None])
    est = Trajectory(np.concatenate([kf.timestamps + 3e-5, stray.timestamps]),
                     np.concatenate([kf.positions, stray.positions]), np.concatenate([kf.rotations, stray.rotations]))
    res = evaluate(_result(tmp_path / "out", est), data, write=False)
    assert res.estimated_poses == len(kf) + 1 and res.associated_poses == len(kf)
    assert res.ate_rigid.rmse < 1e-9
    assert not (tmp_path / "out" / "metrics.json").exists()
    assert any("junctions.yaml" in n for n in res.notes)


def test_associate_is_nearest_within_tolerance_and_one_to_one():
    gt_t = np.arange(10) / FPS
    est_t = np.array([gt_t[5] + 5e-5, gt_t[2], gt_t[7] + 5e-3, gt_t[2] - 2e-5, gt_t[9]])
    e, g = associate(est_t, gt_t)
    # in time order; the later duplicate of 2 and 7+5ms dropped
    assert e.tolist() == [3, 0, 4] and g.tolist() == [2, 5, 9]
    assert associate(np.zeros(0), gt_t)[0].size == 0


def test_junctions_match_by_first_visit_order(tmp_path):
    route = ("T4", "T3", "T2", "T1", "T4")
    data, gt = _loop(tmp_path, route)
    res = evaluate(_result(tmp_path / "out", gt, _true_junctions(route)), data)
    assert res.junctions.matches == (("T4", "J0"), ("T3", "J1"), ("T2", "J2"), ("T1", "J3"))
    assert all(abs(p.error) < 1e-9 for p in res.junctions.pairs)
    assert [p.truth_ids for p in res.junctions.pairs][:4] == [("T4", "T3"), ("T3", "T2"), ("T2", "T1"), ("T1", "T4")]
    # Listed out of visiting order, the same centroids no longer match.
    wrong = evaluate(_result(tmp_path / "out2", gt, _true_junctions(("T1", "T3", "T2", "T4"))), data)
    assert wrong.junctions.max_abs_error > 1.0


def test_missing_junction_is_reported_not_hidden():
    truth = {j: c for j, c in CORNERS.items()}
    table = junction_table(["A", "B", "C"], np.stack([CORNERS["T1"], CORNERS["T2"], CORNERS["T3"]]),
                           ["T1", "T2", "T3", "T4", "T1"], truth)
    assert not table.counts_agree and table.estimated_count == 3 and table.truth_count == 4
    assert ({frozenset(p.truth_ids) for p in table.pairs}
            == {frozenset(p) for p in [("T1", "T2"), ("T2", "T3"), ("T1", "T3")]})
    assert route_pairs(["T1", "T2", "T3"]) == [("T1", "T2"), ("T2", "T3"), ("T1", "T3")]


def _straight(tmp_path, profile_gt, profile_est):
    """A straight pipe along a tilted axis; the estimate lives in its own rotated frame."""
    start, axis = np.array([1.0, 2.0, 0.5]), np.array([1.0, 1.0, 0.1]) / np.linalg.norm([1.0, 1.0, 0.1])
    network = PipeNetwork(0.0767, (Segment("S1", start, start + 7.0 * axis),))
    n = len(profile_gt)
    side = np.cross(axis, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    wobble = 0.01 * np.sin(np.arange(n))[:, None] * side + np.array([0.0, 0.0, -0.02])  # off-centre, swaying
    rot = np.repeat(look_rotation(axis, np.array([0.0, 0.0, 1.0]))[None], n, axis=0)
    gt = Trajectory(np.arange(n) / FPS, start + profile_gt[:, None] * axis + wobble, rot)
    R_own, t_own = exp_so3(np.array([0.4, 0.1, -2.0])), np.array([-3.0, 0.2, 1.0])
    est = Trajectory(gt.timestamps, profile_est[:, None] * (R_own @ axis) + t_own, rot)
    data = _dataset(tmp_path / "data", network, gt)
    return evaluate(_result(tmp_path / "out", est), data)


def test_distance_travelled_forward_run(tmp_path):
    # Table 2a, sparse column: 5844.4 mm true, 5826.5 mm estimated.
    res = _straight(tmp_path, np.linspace(0.0, 5.8444, 60), np.linspace(0.0, 5.8265, 60))
    d = res.distance
    assert not d.forward_and_reverse and d.reverse is None and d.total is None
    assert d.forward.ground_truth == pytest.approx(5.8444, abs=1e-8)
    assert d.forward.estimate == pytest.approx(5.8265, abs=1e-8)
    assert d.forward.error == pytest.approx(0.0179, abs=1e-8)
    assert d.forward.abs_error_pct == pytest.approx(100 * 0.0179 / 5.8444, abs=1e-6)  # 0.306 %


def test_distance_travelled_forward_and_reverse_reproduces_table_2c(tmp_path):
    # Table 2c, dense full-search column: truth 5844.4 mm each way; forward 5858.8, reverse 5893.3.
    up, down = np.linspace(0.0, 1.0, 40), np.linspace(1.0, 0.0, 40)[1:]
    gt_profile = np.concatenate([5.8444 * up, 5.8444 * down])
    est_profile = np.concatenate([5.8588 * up, 5.8588 - 5.8933 * (1.0 - down)])
    res = _straight(tmp_path, gt_profile, est_profile)
    d = res.distance
    assert d.forward_and_reverse
    assert d.forward.error == pytest.approx(-0.0144, abs=1e-8)
    assert d.forward.abs_error_pct == pytest.approx(0.246, abs=5e-4)
    assert d.reverse.estimate == pytest.approx(5.8933, abs=1e-8)
    assert d.reverse.error == pytest.approx(-0.0489, abs=1e-8)
    assert d.reverse.abs_error_pct == pytest.approx(0.837, abs=5e-4)
    assert d.total.ground_truth == pytest.approx(0.0, abs=1e-8)
    assert d.total.estimate == pytest.approx(-0.0345, abs=1e-8)
    assert d.total.error == pytest.approx(0.0345, abs=1e-8)
    assert d.total.abs_error_pct == pytest.approx(100 * 0.0345 / (2 * 5.8444), abs=1e-6)  # eq. 51: 0.295 %
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["distance_travelled"]["turnaround_time_s"] == {"ground_truth": 39 / FPS, "estimate": 39 / FPS}
    assert set(metrics["distance_travelled"]["total"]) == {"ground_truth_m", "estimate_m", "error_m", "abs_error_pct"}


def test_tables_render(tmp_path):
    up, down = np.linspace(0.0, 1.0, 20), np.linspace(1.0, 0.0, 20)[1:]
    res = _straight(tmp_path, np.concatenate([4 * up, 4 * down]), np.concatenate([4.04 * up, 4.04 * down]))
    console = Console(record=True, width=140)
    print_tables(res, console)
    text = console.export_text()
    assert "Table 2" in text and "Total Error ε (mm)" in text and "4040.0" in text
    data, gt = _loop(tmp_path / "loop")
    res = evaluate(_result(tmp_path / "loop" / "out", gt, _true_junctions(("T1", "T2", "T3", "T4"))), data)
    assert len(tables(res)) == 2
    console = Console(record=True, width=140)
    print_tables(res, console)
    assert "T4-T1" in console.export_text()


def _bad(tmp_path, what):
    data, gt = _loop(tmp_path)
    out = _result(tmp_path / "out", gt, _true_junctions(("T1", "T2", "T3", "T4")))
    target = {"trajectory": out / "trajectory.tum", "junctions": out / "junctions.yaml",
              "poses": data / "ground_truth" / "poses.tum", "network": data / "ground_truth" / "network.yaml"}[what[0]]
    if what[1] is None:
        target.unlink()
    else:
        target.write_text(what[1])
    return out, data


@pytest.mark.parametrize(
    "what, message",
    [
        (("trajectory", None), r"trajectory\.tum: trajectory file not found"),
        (("trajectory", "# nothing here\n"), r"trajectory\.tum: trajectory file has no poses"),
        (("trajectory", "1000.0 0 0 0 0 0 0 1\n1001.0 1 0 0 0 0 0 1\n"), r"trajectory\.tum: no timestamps in common"),
        (("trajectory", "0.0 0 0 0 0 0 0 1\n"), r"trajectory\.tum: only 1 timestamp in common"),
        (("junctions", "format: pipemap-junctions/1\njunctions: [{id: A, centroid: [1, 2]}]\n"),
         r"junctions\.yaml: junctions\[0\]\.centroid: expected a list of 3"),
        (("junctions", "format: pipemap-junctions/3\njunctions: []\n"), r"junctions\.yaml: format: expected"),
        (("junctions", "format: pipemap-junctions/1\njunctions: {id: A}\n"),
         r"junctions\.yaml: junctions: expected a list"),
        (("junctions", "format: [unclosed\n"), r"junctions\.yaml: cannot parse YAML"),
        (("junctions", "format: pipemap-junctions/1\n"
                       "junctions: [{id: A, centroid: [0, 0, 0]}, {id: A, centroid: [1, 0, 0]}]\n"),
         r"junctions\.yaml: junctions\[1\]\.id: junction id 'A' appears twice"),
        (("junctions", "format: pipemap-junctions/2\njunctions: [{id: A, type: wye, centroid: [0, 0, 0]}]\n"),
         r"junctions\.yaml: junctions\[0\]\.type: unknown junction type 'wye'"),
        (("junctions", "format: pipemap-junctions/2\njunctions: [{id: A, type: tee, centroid: [0, 0, 0], "
                       "angle_deg: 90}]\n"), r"junctions\.yaml: junctions\[0\]: only an elbow has angle_deg"),
        (("junctions", "format: pipemap-junctions/2\njunctions: [{id: A, type: elbow, centroid: [0, 0, 0], "
                       "bend_radius_m: -0.3}]\n"), r"junctions\.yaml: junctions\[0\]\.bend_radius_m: must be a number"),
        (("junctions", "format: pipemap-junctions/2\njunctions: [{id: A, type: elbow, centroid: [0, 0, 0], "
                       "angle_deg: 200}]\n"), r"junctions\[0\]\.angle_deg: must be a number above 0 and"),
        (("poses", None), r"poses\.tum: no ground-truth poses"),
        (("network", "format: pipemap-network/1\nradius_m: 0\n"), r"network\.yaml: radius_m: must be positive"),
    ],
)
def test_bad_inputs_name_the_file(tmp_path, what, message):
    out, data = _bad(tmp_path, what)
    with pytest.raises(PipemapError, match=message):
        evaluate(out, data)
    assert not (out / "metrics.json").exists()


def test_missing_folders(tmp_path):
    data, _ = _loop(tmp_path)
    with pytest.raises(PipemapError, match="nowhere: result folder not found"):
        evaluate(tmp_path / "nowhere", data)
    with pytest.raises(PipemapError, match="nodata: dataset folder not found"):
        evaluate(data, tmp_path / "nodata")


def test_network_is_optional(tmp_path):
    data, gt = _loop(tmp_path)
    (data / "ground_truth" / "network.yaml").unlink()
    res = evaluate(_result(tmp_path / "out", gt), data)
    assert res.distance is None and res.junctions is None and "network.yaml" in res.notes[0]


def test_section_errors_measure_each_straight_section():
    from pipemap.evaluation.sections import section_errors
    from pipemap.trajectory import Trajectory

    ts = np.arange(200) / 7.5
    gt = Trajectory(ts, np.column_stack([np.linspace(0, 4, 200), np.zeros(200), np.zeros(200)]),
                    np.tile(np.eye(3), (200, 1, 1)))
    est_pos = gt.positions.copy()
    est_pos[100:] = est_pos[100] + 1.01 * (est_pos[100:] - est_pos[100])  # the second section 1 % long
    est = Trajectory(ts, est_pos, gt.rotations)
    rows = section_errors([{"section": 0, "first_keyframe": 0, "last_keyframe": 99},
                           {"section": 2, "first_keyframe": 100, "last_keyframe": 199},
                           {"section": 4, "first_keyframe": 10, "last_keyframe": 12}], est, gt)
    assert [r.section for r in rows] == [0, 2]  # the 4 cm section is too short to judge
    assert abs(rows[0].error_pct) < 1e-9 and rows[1].error_pct == pytest.approx(1.0, rel=1e-6)
