"""An elbow's wall piece in the viewer: its outline follows the arc in 3D (headless Chromium against the exact
arc), and its unrolled wall reads as one of the walls."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from pipemap.config import Settings
from pipemap.mapping import ElbowPiece, WallPiece
from pipemap.viewer.headless import chromium, load_page
from pipemap.viewer.page import viewer_data, write_viewer

UP = [0.0, 0.0, 1.0]


def elbow_result(folder: Path) -> tuple[Path, list]:
    """elbow-cross's E1 (90 deg, bend radius 0.45 m) between its straight pipes."""
    pieces = [WallPiece("S0", [0.0, 0, 0], [1.55, 0, 0], 0.15, UP),
              ElbowPiece("E1", [1.55, 0, 0], [1.55, 0.45, 0], UP, 90.0, 0.15, UP),
              WallPiece("S2", [2.0, 0.45, 0], [2.0, 1.6, 0], 0.15, UP)]
    folder.mkdir()
    (folder / "run.json").write_text(json.dumps({"format": "pipemap-run/2", "method": "network", "pipe_radius_m": 0.15,
                                                 "wall_pieces": [p.to_dict() for p in pieces]}))
    return folder, pieces


def test_the_viewer_reads_an_elbow_piece(tmp_path):
    result, pieces = elbow_result(tmp_path / "r")
    data, _ = viewer_data(result, None, Settings())
    arc = next(p for p in data["pieces"] if p["name"] == "E1")
    assert arc["kind"] == "arc" and arc["angle_deg"] == pytest.approx(90.0, abs=1e-4)
    np.testing.assert_allclose(arc["centre"], pieces[1].centre, atol=1e-4)


def test_the_elbow_outline_follows_its_arc_in_chromium(tmp_path):
    if chromium() is None:
        if os.environ.get("PIPEMAP_REQUIRE_CHROMIUM") == "1":
            pytest.fail("PIPEMAP_REQUIRE_CHROMIUM=1 but no chromium on PATH")
        pytest.skip("no chromium on PATH (apt-get install chromium)")
    result, pieces = elbow_result(tmp_path / "r")
    load = load_page(write_viewer(result, settings=Settings()).path)
    assert load.ready and load.errors == [], load.console
    drawn = {f.split(":")[0]: f.split(":")[1:] for f in load.attributes["data-outlines"].split()}
    assert drawn["E1"][0] == "arc" and drawn["S0"][0] == "line"
    for p in pieces:  # the page's axis middle against the exact one, to its 0.1 mm print
        mid = p.axis_at([0.5 * p.length])[0][0] if p.kind == "arc" else 0.5 * (p.start + p.end)
        np.testing.assert_allclose([float(v) for v in drawn[p.name][1:]], mid, atol=1e-4)
    assert int(load.attributes["data-drawn-pixels"]) > 500
