"""The network pipeline with a forward-looking perspective camera (a sewer crawler's CCTV: 100 deg,
barrel distortion, 1 deg wobble) through the first tee of cctv-loop, and `--method auto` choosing it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from pipemap.config import load_settings
from pipemap.dataset import load_dataset
from pipemap.evaluation import evaluate
from pipemap.network import load_network
from pipemap.pipeline import run_pipeline
from pipemap.view import ALONG, NETWORK_METHOD, camera_view

SIM = dict(width=640, height=480, frames=75, seed=0, spacing_m=0.02)


@pytest.fixture(scope="module")
def cctv_run(tmp_path_factory):
    from pipemap.sim.simulate import simulate

    base = tmp_path_factory.mktemp("cctv")
    data = simulate("cctv-loop", base / "data", **SIM)
    res = run_pipeline(data, base / "out", load_settings())
    return data, res


def test_forward_camera_maps_through_a_tee(cctv_run):
    data, res = cctv_run
    run = json.loads((res.out_dir / "run.json").read_text())
    assert [s["kind"] for s in run["sections"]] == ["straight", "junction", "straight"]
    m = evaluate(res.out_dir, data, write=False)
    # 1.5 m of pipe, metric from the 150 mm radius alone: sub-millimetre (measured 0.3 mm)
    assert m.ate_rigid.rmse < 0.001
    assert abs(m.path_length_error_pct) < 0.2
    j = yaml.safe_load((res.out_dir / "junctions.yaml").read_text())["junctions"]
    assert len(j) == 1
    truth = load_network(data / "ground_truth" / "network.yaml").junction("T1").centroid
    est = m.ate_rigid.alignment.apply(np.array(j[0]["centroid"]))
    assert np.linalg.norm(est - truth) < 0.015  # a tenth of the radius


def test_appearance_band_follows_the_perspective_view(cctv_run):
    data, res = cctv_run
    run = json.loads((res.out_dir / "run.json").read_text())
    lo, hi = run["appearance"]["colatitude_band_deg"]
    widest = np.degrees(load_dataset(data).camera.view_colatitudes()[1])
    assert hi == pytest.approx(widest, abs=0.01) and lo == pytest.approx(hi * 5 / 9, abs=0.01)
    assert run["appearance"]["appearance_points"] > 10000


def test_auto_sees_a_camera_looking_along_the_pipe(cctv_run):
    data, _ = cctv_run
    view = camera_view(load_dataset(data))
    assert view.looks == ALONG and view.method == NETWORK_METHOD
    assert view.travel_deg < 5.0  # the camera looks along the pipe, give or take the robot's wobble


@pytest.mark.parametrize("method", ["dense-hybrid", "sparse-cylinder"])
def test_straight_pipe_methods_refuse_a_camera_looking_along_the_pipe(cctv_run, tmp_path, method):
    """With --method dense-hybrid this camera once gave 2.87 m for an 11.18 m route, silently."""
    from pipemap.errors import PipemapError
    from pipemap.straight import run_dense
    from pipemap.straight.sparse.run import run_sparse

    data, _ = cctv_run
    with pytest.raises(PipemapError, match="the camera looks along the pipe.*use --method network"):
        if method == "sparse-cylinder":
            run_sparse(data, tmp_path / "out", load_settings())
        else:
            run_dense(data, tmp_path / "out", load_settings(), method)
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out*"))


def test_forward_camera_sections_rated_from_their_own_figures(cctv_run):
    _, res = cctv_run
    q = json.loads((res.out_dir / "run.json").read_text())["quality"]
    assert res.quality is not None and q["rating"] == res.quality.rating
    straight = [s for s in q["sections"] if s["kind"] == "straight"]
    assert [s["kind"] for s in q["sections"]] == ["straight", "junction", "straight"]
    # the free radius: the tracks triangulated from the final poses alone lie on the 150 mm wall
    first = straight[0]["figures"]
    assert first["free_radius_points"] >= 30
    assert first["free_radius_m"] == pytest.approx(0.15, rel=0.02)
    assert straight[0]["rating"] == "good", straight[0]["reasons"]
