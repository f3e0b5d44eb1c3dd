"""pipemap demo on a tiny configuration: every file of the result, sane figures, refusing a used folder."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from pipemap.cli import app
from pipemap.demo import run_demo
from pipemap.errors import PipemapError

TINY = dict(width=320, height=240, frames=60)


def test_demo_writes_everything(tmp_path):
    stages = set()
    s = run_demo(tmp_path / "demo", progress=lambda stage, done, total: stages.add(stage), **TINY)
    assert stages == {"rendering", "mapping"}
    result = tmp_path / "demo" / "result"
    for name in ("trajectory.tum", "junctions.yaml", "run.json", "metrics.json", "report.html", "appearance.ply",
                 "report/trajectory.png", "viewer.html"):
        assert (result / name).is_file(), name
    assert list((result / "unrolled").glob("*.png")) and list((result / "unrolled").glob("*.json"))
    assert (tmp_path / "demo" / "dataset" / "ground_truth" / "poses.tum").is_file()
    assert s.frames == 60 and 10 < s.keyframes <= 60
    assert s.report == result / "report.html" and s.viewer == result / "viewer.html"
    # the first 1.2 m of the loop, through T1: the figures the summary prints are real and small
    assert abs(s.path_length_error_pct) < 10.0
    assert s.ate_rmse_m < 0.1
    assert s.appearance_points > 100_000
    # 320x240 has a quarter of the preset's pixels: the map still lies within a few mm of the wall
    assert s.appearance_wall["global"]["points"] == s.appearance_points
    assert s.appearance_wall["local"]["median_mm"] < 3.0
    run = json.loads((result / "run.json").read_text())
    assert run["appearance"]["appearance_points"] == s.appearance_points
    assert "Errors against ground truth" in s.report.read_text()
    assert set(s.seconds) == {"simulate", "run", "maps", "evaluate", "report", "total"}


def test_demo_refuses_a_used_folder(tmp_path):
    out = tmp_path / "used"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(PipemapError, match="not empty"):
        run_demo(out, **TINY)
    r = CliRunner().invoke(app, ["demo", "--out", str(out)])
    assert r.exit_code == 2
    assert "not empty" in r.output and "Traceback" not in r.output
    assert (out / "keep.txt").read_text() == "mine"


def test_force_replaces_only_an_earlier_demo(tmp_path):
    from pipemap.demo import _prepare

    out = tmp_path / "again"
    (out / "dataset" / "images").mkdir(parents=True)
    (out / "result").mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(PipemapError, match="--force"):
        _prepare(out, force=False)
    _prepare(out, force=True)
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
