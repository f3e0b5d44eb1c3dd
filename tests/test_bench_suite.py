"""The benchmark suite's table writer (benchmarks/suite_tables.py) and result collection (benchmarks/run.py)
on canned bench-script JSON: no rendering, no timing."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def load(name: str):
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))  # run.py imports suite_tables as a sibling, as when run as a script
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


tables = load("suite_tables")


def network_case(frames, wall, seconds, pairs=None, rss=300.0):
    return {
        "frames": frames, "keyframes": frames // 3, "wall_s": wall, "cpu_s": wall * 1.3, "peak_rss_mb": rss,
        "ms_per_frame": round(1000 * wall / frames, 2), "frames_per_s": round(frames / wall, 2), "seconds": seconds,
        "path_length_error_pct": -0.141, "ate_rigid_m": 0.0029, "ate_rigid_pct_of_path": 0.059,
        "ate_sim3_pct_of_path": 0.058,
        "table_i": pairs, "table_i_max_abs_pct": None if pairs is None else max(abs(p["error_pct"]) for p in pairs),
        "junctions": {"estimated": 4, "truth": 4}, "sections": [], "problems": ["one"],
    }


def pair(name, truth, est):
    return {"pair": name, "truth_m": truth, "estimate_m": est, "error_m": est - truth,
            "error_pct": 100 * (est - truth) / truth}


@pytest.fixture
def results():
    seconds = {"frontend": 100.0, "classification": 4.0, "straight_windows": 50.0, "total": 160.0, "write": 0.5}
    pairs_a = [pair("T1-T2", 8.135, 8.175), pair("T2-T3", 8.159, 8.150)]
    pairs_b = [pair("T1-T2", 8.135, 8.130)]
    network = {
        "machine": {"cpus": 2}, "size": "1280x960",
        "A": network_case(3000, 400.0, seconds, pairs_a),
        "B": network_case(3600, 450.0, seconds, pairs_b, rss=420.0),
        "A-half": network_case(1500, 195.0, {"frontend": 50.0, "total": 80.0}),
    }
    dense = {"results": [{
        "case": "6in-forward-reverse", "method": "dense-hybrid", "metric": "zncc", "frames": 590,
        "frames_per_second": 118.4,
        "forward": {"ground_truth_mm": 2000.0, "estimate_mm": 1996.0, "error_mm": 4.0, "abs_error_pct": 0.2},
        "reverse": {"ground_truth_mm": 2000.0, "estimate_mm": 2001.0, "error_mm": -1.0, "abs_error_pct": 0.05},
        "total": {"ground_truth_mm": 0.0, "estimate_mm": -5.0, "error_mm": 5.0, "abs_error_pct": 0.125},
        "report_abs_error_pct": {"forward": [0.246, 0.149], "reverse": [0.837, 0.361], "total": [0.295, 0.255]},
    }]}
    peer = {
        "frames": 500, "crop_fov_deg": 120.0, "pycolmap_version": "4.2.1",
        "pycolmap": {"wall_s": 400.0, "cpu_s": 700.0, "registered_images": 450,
                     "accuracy": {"ate_sim3_m": 0.010, "ate_sim3_pct_of_path": 0.2}},
        "pipemap": {"wall_s": 40.0, "cpu_s": 50.0, "keyframes": 180,
                    "accuracy": {"ate_sim3_m": 0.002, "ate_sim3_pct_of_path": 0.04}},
        "common_frames": {"frames": 170, "pipemap_ate_sim3_m": 0.002, "pycolmap_ate_sim3_m": 0.012},
        "ratios": {"speedup_wall": 10.0, "speedup_cpu": 14.0, "ate_sim3_peer_over_pipemap": 5.0,
                   "ate_sim3_common_peer_over_pipemap": 6.0, "registered_fraction": 0.9},
    }
    return {"network-1280x960": network, "network-640x480": tables.not_run("left out by --only"), "dense": dense,
            "sparse": tables.not_run("benchmarks/bench_sparse.py not found"), "peer-colmap": peer}


def rows_of(md: str, first_cell: str) -> list[list[str]]:
    """The cells of every table row whose first cell starts with `first_cell`."""
    out = []
    for line in md.splitlines():
        if line.startswith("| "):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if cells[0].startswith(first_cell):
                out.append(cells)
    return out


def test_stage_table_rates_and_memory(results):
    md = tables.stage_table(results)
    header = rows_of(md, "run")[0]
    assert header[5:8] == ["frontend frames/s", "classification frames/s", "straight_windows frames/s"]
    assert "write frames/s" == header[8] and header[-1] == "peak RSS MB"
    a = rows_of(md, "1280x960 A")[0]
    assert float(a[4]) == pytest.approx(3000 / 400.0, abs=0.01)
    assert float(a[5]) == pytest.approx(30.0, abs=0.05)  # 3000 frames / 100 s of front end
    assert float(a[7]) == pytest.approx(60.0, abs=0.05)
    assert float(rows_of(md, "1280x960 B")[0][-1]) == pytest.approx(420.0)
    half = rows_of(md, "1280x960 A-half")[0]
    assert half[6] == "–"  # a stage the run did not report
    assert rows_of(md, "network-640x480")[0][1] == "not run: left out by --only"


def test_length_table_ratio(results):
    md = tables.length_table(results)
    row = rows_of(md, "1280x960")[0]
    assert float(row[2]) == pytest.approx(130.0, abs=0.05) and float(row[4]) == pytest.approx(133.3, abs=0.05)
    assert float(row[5]) == pytest.approx((400 / 3000) / (195 / 1500), abs=1e-3)
    assert rows_of(md, "network-640x480")[0][1].startswith("not run:")


def test_table_i_routes_and_paper(results):
    md = tables.table_i(results)
    t12 = [r for r in rows_of(md, "1280x960") if r[1] == "T1-T2"][0]
    assert float(t12[2]) == pytest.approx(8.135)
    assert float(t12[4]) == pytest.approx(100 * 0.040 / 8.135, abs=0.005)
    assert float(t12[5]) == pytest.approx(0.42) and float(t12[8]) == pytest.approx(-0.44)
    assert float(t12[7]) == pytest.approx(-100 * 0.005 / 8.135, abs=0.005)
    t23 = [r for r in rows_of(md, "1280x960") if r[1] == "T2-T3"][0]
    assert t23[6] == "–" and t23[7] == "–"  # route B found no T2-T3 pair
    worst_a = [r for r in rows_of(md, "1280x960") if r[1] == "max abs, route A"][0]
    assert worst_a[-1].startswith(f"{100 * 0.040 / 8.135:.2f} %")


def test_table_2_legs_and_not_run(results):
    md = tables.table_2(results)
    rows = rows_of(md, "dense-hybrid/zncc")
    assert [r[3] for r in rows] == ["forward", "reverse", "total"]
    assert float(rows[0][6]) == pytest.approx(0.2) and rows[0][7] == "0.246 (full search)"
    assert float(rows[2][6]) == pytest.approx(0.125) and rows[2][7] == "0.295 (full search)"
    assert rows_of(md, "sparse")[0][1] == "not run: benchmarks/bench_sparse.py not found"


def test_peer_table_and_goals(results):
    md = tables.peer_table(results)
    mine, theirs, ratio = (rows_of(md, "pipemap")[0], rows_of(md, "pycolmap 4.2.1")[0],
                           rows_of(md, "pycolmap / pipemap")[0])
    assert float(mine[3]) == pytest.approx(50.0) and float(theirs[3]) == pytest.approx(700.0)
    assert float(mine[4]) == pytest.approx(12.5) and float(theirs[4]) == pytest.approx(1.25)
    assert float(mine[6]) == pytest.approx(2.0) and float(theirs[6]) == pytest.approx(10.0)
    assert float(theirs[8]) == pytest.approx(12.0)
    assert ratio[2] == "10.00×" and ratio[3] == "14.00×" and ratio[8].startswith("6.00×")
    goals = tables.goals(results)
    assert goals[0].startswith("Goal ≥ 7.5 frames/s at 1280x960: met (slowest run 7.50")  # A 7.5, B 8, A-half 7.69
    assert goals[1].startswith("Goal ≥ 10× faster than pycolmap with better accuracy: met")


def test_slow_goal_and_missing_peer(results):
    results["network-1280x960"]["A"]["frames_per_s"] = 7.49
    results["network-1280x960"]["A-half"]["frames_per_s"] = 7.6
    results["peer-colmap"] = {"frames": 500,
                              "pycolmap": tables.not_run("pycolmap is not installed (pip install pycolmap)")}
    goals = tables.goals(results)
    assert "NOT met (slowest run 7.49" in goals[0]
    assert goals[1].endswith("not run: pycolmap is not installed (pip install pycolmap)")
    md = tables.peer_table(results)
    assert rows_of(md, "pycolmap")[0][1] == "not run: pycolmap is not installed (pip install pycolmap)"
    assert rows_of(md, "pipemap")[0][1] == "not run: not in the results"
    assert not rows_of(md, "pycolmap / pipemap")


def test_everything_missing_renders():
    md = tables.markdown("quick", {}, [{"name": "network-320x240",
                                        "status": "not run: benchmarks/bench_network.py not found"}])
    assert "| network | not run: no result |" in md
    assert "| pycolmap peer | not run: no result |" in md
    assert "| network-320x240 | not run: benchmarks/bench_network.py not found | – | – |" in md
    assert md.count("## ") == 8


def test_run_step_collects_json_and_reports_failures(tmp_path, monkeypatch):
    run = load("run")
    monkeypatch.setattr(run, "HERE", tmp_path)
    (tmp_path / "bench_ok.py").write_text(
        "import json, sys\nout = sys.argv[sys.argv.index('--out') + 1]\n"
        "open(out, 'w').write(json.dumps({'results': [], 'value': 3.5}))\n")
    (tmp_path / "bench_fail.py").write_text("import sys\nsys.exit('bench_fail: no dataset at /nowhere')\n")
    (tmp_path / "bench_silent.py").write_text("pass\n")
    (tmp_path / "bench_fixed.py").write_text(
        "import json, pathlib\np = pathlib.Path(__file__).parent / 'results' / 'fixed.json'\n"
        "p.parent.mkdir(exist_ok=True)\np.write_text(json.dumps({'size': '640x480'}))\n")
    with open(tmp_path / "log.txt", "w") as log:
        ok, rec = run.run_step(run.Step("ok", "bench_ok.py", ["--out", "{out}"], "{out}"), tmp_path,
                               tmp_path / "ok.json", log)
        assert ok == {"results": [], "value": 3.5} and rec["status"] == "ok"
        assert json.loads((tmp_path / "ok.json").read_text())["value"] == 3.5
        failed, rec = run.run_step(run.Step("fail", "bench_fail.py", [], "{out}"), tmp_path, tmp_path / "f.json", log)
        assert failed == {"not_run": "failed (exit 1): bench_fail: no dataset at /nowhere"}
        silent, _ = run.run_step(run.Step("silent", "bench_silent.py", [], "{out}"), tmp_path, tmp_path / "s.json", log)
        assert silent == {"not_run": "finished but wrote no s.json"}
        fixed, _ = run.run_step(run.Step("fixed", "bench_fixed.py", [], "results/fixed.json"), tmp_path,
                                tmp_path / "fixed-copy.json", log)
        assert fixed == {"size": "640x480"} and json.loads((tmp_path / "fixed-copy.json").read_text()) == fixed
        stale, _ = run.run_step(run.Step("stale", "bench_silent.py", [], "results/fixed.json"), tmp_path,
                                tmp_path / "stale.json", log)
        assert stale == {"not_run": "finished but wrote no fixed.json"}  # an older file is not this run's result
        absent, rec = run.run_step(run.Step("x", "bench_absent.py", [], "{out}"), tmp_path, tmp_path / "x.json", log)
        assert absent == {"not_run": "benchmarks/bench_absent.py not found"} and rec["status"].startswith("not run:")
        missing, _ = run.run_step(run.Step("p", "bench_ok.py", [], "{out}", needs=["no_such_module_xyz"]), tmp_path,
                                  tmp_path / "p.json", log)
        assert missing == {"not_run": "no_such_module_xyz is not installed (pip install no_such_module_xyz)"}


def fisheye_640():
    from pipemap.camera import PolynomialCamera

    return PolynomialCamera(640, 480, dict(k1=145.0, k2=-4.0, k3=1.0, k4=-0.2, u0=319.2, v0=239.7), 95.0)


def test_peer_view_maps_the_central_field_of_view():
    peer = load("peer_colmap")
    cam = fisheye_640()
    map_x, map_y, mask, params = peer.equidistant_view(cam, 120.0)
    size = mask.shape[0]
    c = (size - 1) // 2
    assert size == 2 * int(np.ceil(145.0 * np.radians(60.0))) + 1
    assert (map_x[c, c], map_y[c, c]) == pytest.approx((319.2, 239.7), abs=1e-4)  # the axis stays the axis
    # A view pixel at radius r is the bearing at colatitude r / f: check one on each axis against the fisheye.
    r = 100
    theta = r / 145.0
    for (du, dv), phi in (((r, 0), 0.0), ((0, r), np.pi / 2), ((-r, 0), np.pi)):
        b = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        uv, ok = cam.project(b)
        assert ok and (map_x[c + dv, c + du], map_y[c + dv, c + du]) == pytest.approx(tuple(uv), abs=1e-3)
    inside = mask > 0
    yy, xx = np.mgrid[0:size, 0:size]
    radius = np.hypot(xx - c, yy - c)
    assert (inside[radius <= 145.0 * np.radians(60.0) - peer.MASK_MARGIN_PX].all()
            and not inside[radius > 145.0 * np.radians(60.0)].any())
    assert params == pytest.approx([145.0, 145.0, c + 0.5, c + 0.5, 0, 0, 0, 0])


def test_peer_view_agrees_with_colmaps_camera_model():
    pycolmap = pytest.importorskip("pycolmap")
    peer = load("peer_colmap")
    cam = fisheye_640()
    map_x, map_y, mask, params = peer.equidistant_view(cam, 120.0)
    colmap_cam = pycolmap.Camera(model="OPENCV_FISHEYE", width=mask.shape[1], height=mask.shape[0], params=params)
    rng = np.random.default_rng(3)
    v, u = np.nonzero(mask)
    pick = rng.choice(len(u), 200, replace=False)
    pixels = np.stack([u[pick], v[pick]], axis=1).astype(float)
    # COLMAP puts pixel centres at +0.5; its ray for each view pixel must land where the remap table reads the frame.
    xy = colmap_cam.cam_from_img(pixels + 0.5)
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    uv, ok = cam.project(rays / np.linalg.norm(rays, axis=1, keepdims=True))
    assert ok.all()
    np.testing.assert_allclose(uv[:, 0], map_x[v[pick], u[pick]], atol=2e-3)
    np.testing.assert_allclose(uv[:, 1], map_y[v[pick], u[pick]], atol=2e-3)
