"""Routes through junctions as real networks have them (issue 20): tees passed straight through, a tee
approached head-on along its stem."""

import numpy as np
import pytest

from pipemap.sim.simulate import plan


def _unit(v):
    return v / np.linalg.norm(v)


def _tangent_near(p, centre, within):
    """Path tangents at every 1 cm within `within` metres of arc length of the path vertex at `centre`."""
    k = int(np.flatnonzero(np.linalg.norm(p.path.vertices - centre, axis=1) < 1e-9)[0])
    s0 = p.path.vertex_s[k]
    _, tan = p.path.evaluate(np.arange(s0 - within, s0 + within, 0.01))
    return tan


@pytest.mark.parametrize("route, visits", [("A", ["T1", "T4", "T3", "T2", "T1"]), ("B", ["T1", "T4", "T3", "T2"])])
def test_tee_pass_routes_visit_in_order_and_stay_inside(route, visits):
    p = plan("tee-pass-loop", route=route, seed=3)
    assert p.visits == visits
    scene = p.setup.scene
    assert scene.radius == 0.15 and (p.setup.camera.width, p.setup.camera.height) == (640, 480)
    pos = p.trajectory.positions
    assert scene.contains(pos).all()
    # the robot drives 4 cm below the axis (+- 2 mm wobble); in a turn its fillet (radius r) cuts the corner
    # by at most r (1 - 1 / sqrt 2) across both axes
    cut = 0.15 * (1 - np.sqrt(0.5))
    assert scene.axis_distance(pos).max() < np.hypot(0.04 + 0.0021, cut) + 1e-6
    # it starts 0.75 m before T1, in T1's stub, heading at T1
    t1 = scene.runs["B1"][0]
    assert abs(np.linalg.norm(pos[0][:2] - t1[:2]) - 0.75) < 0.003


@pytest.mark.parametrize("route, straight", [("A", ["T1"]), ("B", ["T1", "T2"])])
def test_tees_passed_straight_through_keep_the_heading(route, straight):
    p = plan("tee-pass-loop", route=route, seed=3)
    scene = p.setup.scene
    for tid in straight:
        k = int(tid[1:])
        stub = scene.runs[f"B{k}"]
        main = _unit(stub[1] - stub[0])  # the stub continues the main pipe exactly
        tan = _tangent_near(p, stub[0], 0.4)
        # within 0.4 m either side of the centre the robot heads along the main pipe, no turn
        assert np.abs(np.abs(tan @ main) - 1).max() < 1e-9
        # and a side branch leaves the tee at right angles to it (to within the joints' misalignment)
        branch = [rid for rid, v in scene.runs.items() if rid.startswith("S") and
                  min(np.linalg.norm(v[[0, -1]] - stub[0], axis=1)) < 1e-9]
        dirs = [_unit(v[1] - v[0]) if np.linalg.norm(v[0] - stub[0]) < 1e-9 else _unit(v[-2] - v[-1])
                for v in (scene.runs[b] for b in branch)]
        assert sorted(abs(float(d @ main)) for d in dirs)[0] < 0.01  # one of the two sides is the branch
        assert sorted(abs(float(d @ main)) for d in dirs)[1] > 0.99  # the other is the main pipe


def test_last_tee_is_met_head_on_along_its_stem():
    p = plan("tee-pass-loop", route="A", seed=3)
    scene = p.setup.scene
    stub = scene.runs["B1"]
    main = _unit(stub[1] - stub[0])
    s1 = scene.runs["S1"]
    stem = _unit(s1[0] - s1[1])  # the branch's last piece, pointing at T1
    assert abs(float(stem @ main)) < 0.01
    # the last lap's final 0.8 m before T1 heads straight at the centre along the stem
    s_t1 = p.path.vertex_s[-2]
    pos, tan = p.path.evaluate(np.linspace(s_t1 - 0.8, s_t1 - 0.16, 30))
    assert np.abs(tan @ stem - 1).max() < 1e-9
    lateral = (stub[0] - pos) - ((stub[0] - pos) @ stem)[:, None] * stem
    assert np.linalg.norm(lateral, axis=1).max() < 1e-9
    # and the drive ends 0.5 m into T1's stub, having turned there
    end = p.trajectory.positions[-1]
    assert abs((end - stub[0]) @ main - 0.5) < 0.005
