"""pipemap report: the viewer's data against the result's exact geometry, its inputs and errors, and the page
itself in headless Chromium (skipped without chromium unless PIPEMAP_REQUIRE_CHROMIUM=1)."""

from __future__ import annotations

import base64
import json
import math
import os

import numpy as np
import pytest
from typer.testing import CliRunner

from pipemap.cli import app
from pipemap.config import Settings, load_settings
from pipemap.viewer import write_viewer
from pipemap.viewer.headless import chromium, load_page
from pipemap.viewer.page import viewer_data
from pipemap.viewer.walls import place_observation, read_walls

from viewer_helpers import (DEFORMATION_COLUMNS, OBSERVATION_COLUMNS, copy_result, deformation_rows, observation_rows,
                       wall_point, write_csv)

CHAINAGE0 = {"S1.1": 0.75, "S4.2": 0.0}  # the route: S4.2 (0.75 m) into T1, then S1.1


def test_markers_land_where_the_wall_points_are(viewer_case, tmp_path):
    """200 random wall points: the marker's column and row are the point's h and clock on the unrolled image
    (exact geometry: to 1e-6 px), whether placed by the point or, with /2 sidecars, by chainage and clock."""
    result = copy_result(viewer_case, tmp_path / "r", CHAINAGE0)
    walls = {w.name: w for w in read_walls(result)}
    rng = np.random.default_rng(1)
    for _ in range(200):
        piece = viewer_case.pieces[rng.integers(len(viewer_case.pieces))]
        h, clock = rng.uniform(0, piece.length), rng.uniform(0, 360)
        w = walls[piece.name]
        want_col, want_row = h / w.along_per_px, (clock / 360 * w.height) % w.height  # rows: clock turns anticlockwise
        want_row = (-want_row) % w.height
        x = wall_point(piece, h, clock)
        by_point = place_observation({"x": x[0], "y": x[1], "z": x[2]}, list(walls.values()))
        by_chainage = place_observation({"section": piece.name, "chainage_m": CHAINAGE0[piece.name] + h,
                                         "clock_from_deg": clock}, list(walls.values()))
        for m in (by_point, by_chainage):
            assert m["wall"] == piece.name
            assert m["col"] == pytest.approx(want_col, abs=1e-6)
            assert min(abs(m["row"] - want_row), w.height - abs(m["row"] - want_row)) < 1e-6
        assert float(w.along_of_column(want_col)) == pytest.approx(CHAINAGE0[piece.name] + h, abs=1e-9)
        assert float(w.clock_deg_of_row(want_row)) == pytest.approx(clock, abs=1e-6)


def test_a_stretch_spans_its_chainage_and_clock(viewer_case, tmp_path):
    result = copy_result(viewer_case, tmp_path / "r", CHAINAGE0)
    walls = read_walls(result)
    crack = observation_rows(viewer_case.pieces, CHAINAGE0)[2]
    m = place_observation(crack, walls)
    w = next(w for w in walls if w.name == m["wall"])
    assert (m["col2"] - m["col"]) * w.along_per_px == pytest.approx(0.1, abs=1e-9)
    # 1 to 4 o'clock is 90 deg clockwise: a quarter of the rows, upwards on the image seen from inside
    assert m["row2"] - m["row"] == pytest.approx(-w.height / 4, abs=1e-6)


def test_a_point_off_every_wall_gets_no_marker(viewer_case):
    walls = read_walls(viewer_case.result)
    far = viewer_case.pieces[0].start + [0.0, 0.0, 5.0]
    assert place_observation({"x": far[0], "y": far[1], "z": far[2]}, walls) is None


def test_viewer_data_of_a_full_result(viewer_case, tmp_path):
    result = copy_result(viewer_case, tmp_path / "r", CHAINAGE0)
    write_csv(result / "deformation.csv", DEFORMATION_COLUMNS, deformation_rows(viewer_case.pieces, CHAINAGE0))
    write_csv(result / "observations.csv", OBSERVATION_COLUMNS, observation_rows(viewer_case.pieces, CHAINAGE0))
    s = write_viewer(result, settings=load_settings(overrides=["viewer.cloud_points=5000"]))
    assert s.path == result / "viewer.html" and s.walls == 2 and s.cloud_points == 5000
    assert s.observations == 3 and s.placed == 3
    assert s.deformation_rows == 2 * sum(len(np.arange(0.05, p.length, 0.1)) for p in viewer_case.pieces)
    assert s.missing == []
    text = s.path.read_text()
    # offline: nothing the page loads comes from a server
    assert 'src="http' not in text and 'href="http' not in text and "<link" not in text


def test_the_cloud_sample_is_seeded_and_lies_on_the_wall(viewer_case):
    """The sample holds real map points: on the true pipe wall to the map's accuracy (mean grey level of
    keyframes at the true poses: within 1 mm), the same for the same seed."""
    settings = load_settings(overrides=["viewer.cloud_points=3000"])
    a, _ = viewer_data(viewer_case.result, None, settings)
    b, _ = viewer_data(viewer_case.result, None, settings)
    assert a["cloud"] == b["cloud"] and a["cloud"]["count"] == 3000
    xyz = np.frombuffer(base64.b64decode(a["cloud"]["xyz"]), "<f4").reshape(-1, 3).astype(float)
    off = np.min([np.abs(p.wall_coordinates(xyz)[2] - p.radius) for p in viewer_case.pieces], axis=0)
    assert np.max(off) < 1e-3
    other, _ = viewer_data(viewer_case.result, None, load_settings(overrides=["viewer.cloud_points=3000", "seed=1"]))
    assert other["cloud"]["xyz"] != a["cloud"]["xyz"]


def test_an_older_result_falls_back(viewer_case, tmp_path):
    """/1 sidecars, no run.json, no junctions, no appearance map: the page is still written and says what is
    missing; distances along a wall are h from its piece's start."""
    result = copy_result(viewer_case, tmp_path / "r")
    for name in ("run.json", "junctions.yaml", "appearance.ply"):
        (result / name).unlink()
    data, _ = viewer_data(result, None, Settings())
    assert [w["alongKind"] for w in data["walls"]] == ["h", "h"]
    assert data["walls"][0]["along0"] == 0.0 and data["cloud"] is None
    assert [p["name"] for p in data["pieces"]] == ["S1.1", "S4.2"]
    assert len(data["missing"]) == 6
    assert write_viewer(result).path.is_file()


def test_report_command_and_its_errors(viewer_case, tmp_path):
    result = copy_result(viewer_case, tmp_path / "r")
    runner = CliRunner()
    r = runner.invoke(app, ["report", str(result), "--set", "viewer.cloud_points=1000"])
    assert r.exit_code == 0, r.output
    assert "2 walls, 1000 map points" in r.output
    page = result / "viewer.html"
    first = page.read_bytes()

    def refused(args, *words):
        r = runner.invoke(app, ["report", *args])
        assert r.exit_code == 2, r.output
        assert all(w in r.output for w in words) and "Traceback" not in r.output, r.output

    refused([str(result)], "viewer.html", "already exists")
    refused([str(tmp_path / "nowhere")], "nowhere", "not found")
    (tmp_path / "empty").mkdir()
    refused([str(tmp_path / "empty")], "empty", "not a result folder")
    assert not (tmp_path / "empty" / "viewer.html").exists()
    refused([str(result), "--out", str(result / "run.json"), "--force"], "run.json", "made from")
    bad = write_csv(tmp_path / "obs.csv", ["id", "code", "chainage_m"], [{"id": "O1", "code": "DAM"}])
    refused([str(result), "--observations", str(bad), "--force"], "obs.csv", "no column clock_from_deg")
    bad = write_csv(tmp_path / "obs2.csv", OBSERVATION_COLUMNS, [{"id": "O1", "code": "X", "chainage_m": "1,5",
                                                                  "clock_from_deg": 30}])
    refused([str(result), "--observations", str(bad), "--force"], "obs2.csv", "line 2", "chainage_m")
    (result / "deformation.csv").write_text("piece,h_m\nS1.1,0.1\n")
    refused([str(result), "--force"], "deformation.csv", "ovality_pct")
    assert page.read_bytes() == first  # nothing half-written, nothing replaced by a failed run


def _check_chromium():
    if chromium() is None:
        if os.environ.get("PIPEMAP_REQUIRE_CHROMIUM") == "1":
            pytest.fail("PIPEMAP_REQUIRE_CHROMIUM=1 but no chromium on PATH")
        pytest.skip("no chromium on PATH (apt-get install chromium)")


@pytest.mark.parametrize("chainage", [True, False], ids=["chainage", "h-only"])
def test_the_page_draws_in_chromium_and_a_click_reads_chainage_and_clock(viewer_case, tmp_path, chainage):
    """The page loads from file:// with no errors, draws the 3D view, both walls, the deformation plots and the
    observations; a click on a wall pixel reads its chainage (or h) and clock position, to within one screen
    pixel of the fitted view."""
    _check_chromium()
    result = copy_result(viewer_case, tmp_path / "r", CHAINAGE0 if chainage else None)
    c0 = CHAINAGE0 if chainage else None
    write_csv(result / "deformation.csv", DEFORMATION_COLUMNS, deformation_rows(viewer_case.pieces, c0))
    write_csv(result / "observations.csv", OBSERVATION_COLUMNS, observation_rows(viewer_case.pieces, c0))
    page = write_viewer(result, settings=load_settings(overrides=["viewer.cloud_points=20000"])).path
    wall = next(w for w in read_walls(result) if w.name == "S4.2")
    col, row = 123.0, 0.3 * wall.height
    load = load_page(page, fragment=f"probe={wall.name}:{col}:{row}", window="1200,900")
    attrs = load.attributes
    assert load.ready, (attrs, load.console)
    assert load.errors == []
    assert attrs["data-walls"] == "2"
    assert int(attrs["data-drawn-pixels"]) > 2000  # the cloud, axes and trajectory, not an empty background
    assert load.html.count('class="obs"') == 3 and load.html.count('data-plot="ovality_pct"') == (1 if chainage else 2)
    screen_px = 1.0 / float(attrs["data-probe-scale"])  # image pixels per screen pixel
    along = float(attrs["data-probe-along"])
    assert along == pytest.approx(float(wall.along_of_column(col)), abs=screen_px * wall.along_per_px + 1e-4)
    clock = float(attrs["data-probe-clock"])
    want = float(wall.clock_deg_of_row(row))
    assert abs((clock - want + 180) % 360 - 180) < screen_px * math.degrees(abs(wall.phi_per_row_rad)) + 0.01
    assert json.loads((result / "run.json").read_text())["method"] == "network"
