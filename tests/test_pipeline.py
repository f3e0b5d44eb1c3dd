"""`run_pipeline` end to end on a small fisheye-straight render: the result folder follows
spec/formats.md, the scale is metric without alignment, and two runs give the same files."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from plyfile import PlyData

from pipemap.config import load_settings
from pipemap.dataset import load_dataset
from pipemap.errors import PipemapError
from pipemap.evaluation import evaluate
from pipemap.network import load_network
from pipemap.pipeline import run_pipeline
from pipemap.trajectory import read_tum

SIM = dict(preset="fisheye-straight", width=640, height=480, frames=60, seed=0, spacing_m=0.015)
FILES = ("trajectory.tum", "sparse.ply", "frames.csv", "run.json")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from pipemap.sim.simulate import simulate

    base = tmp_path_factory.mktemp("pipeline")
    kw = dict(SIM)
    data = simulate(kw.pop("preset"), base / "data", **kw)
    calls = []
    first = run_pipeline(data, base / "out1", load_settings(), progress=lambda *a: calls.append(a))
    second = run_pipeline(data, base / "out2", load_settings())
    return data, first, second, calls


def test_result_folder_follows_formats(runs):
    data, res, _, calls = runs
    out = res.out_dir
    ds = load_dataset(data)
    assert all((out / f).is_file() for f in FILES)
    assert not list(out.parent.glob(".out1.partial-*"))
    assert calls[-1][:2] == (SIM["frames"], SIM["frames"])
    traj = read_tum(out / "trajectory.tum")
    assert len(traj) == res.keyframe_count > 20
    with open(out / "frames.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["index"]) for r in rows] == list(range(SIM["frames"]))
    keys = [int(r["index"]) for r in rows if r["keyframe"] == "1"]
    assert {r["label"] for r in rows} == {"straight"}
    assert np.allclose(traj.timestamps, np.array(keys) / ds.fps, atol=1e-6)
    run = json.loads((out / "run.json").read_text())
    assert run["frames"] == SIM["frames"] and run["keyframes"] == len(traj)
    assert (run["format"], run["method"], run["trajectory"]) == ("pipemap-run/2", "network", "keyframes")
    assert run["camera"] == ds.camera.to_dict() and run["mount"] is None and run["problems"] == []
    assert run["settings"]["bundle"]["tau"] == 2.5e5
    assert {"frontend", "straight_relative", "straight_windows", "write"} <= set(run["seconds"])
    assert run["sections"][0]["scale"] == "cylinder" and run["lost_keyframes"] == 0
    assert run["refused_poses"] == run["continued_poses"] == 0  # clean frames: RANSAC's poses are the motion
    ply = PlyData.read(str(out / "sparse.ply"))
    assert not ply.text and ply["vertex"]["x"].dtype == np.float32
    assert len(ply["vertex"]) == run["points"] > 1000


def test_metric_without_alignment(runs):
    data, res, _, _ = runs
    m = evaluate(res.out_dir, data)
    # Measured: 0.1 % of 0.8 m; 1 % leaves room for platform differences.
    assert abs(m.distance.forward.abs_error_pct) < 1.0
    assert m.ate_rmse_pct(m.ate_rigid) < 0.5


def test_sparse_points_on_true_wall(runs):
    """The world frame is the first keyframe's camera: put the points into the true world with that
    keyframe's true pose (no alignment) and measure their distance from the true pipe wall."""
    data, res, _, _ = runs
    out = res.out_dir
    ply = PlyData.read(str(out / "sparse.ply"))["vertex"]
    X = np.stack([ply["x"], ply["y"], ply["z"]], -1).astype(float)
    first = int(read_tum(out / "trajectory.tum").timestamps[0] * load_dataset(data).fps + 0.5)
    gt = read_tum(data / "ground_truth" / "poses.tum")
    Xw = X @ gt.rotations[first].T + gt.positions[first]
    net = load_network(data / "ground_truth" / "network.yaml")
    d = np.full(len(Xw), np.inf)
    for seg in net.segments:
        v = Xw - seg.start
        s = v @ seg.axis
        radial = np.linalg.norm(v - s[:, None] * seg.axis, axis=1)
        on = (s >= 0) & (s <= seg.length)
        d = np.where(on, np.minimum(d, np.abs(radial - net.radius_m)), d)
    assert np.isfinite(d).mean() > 0.99
    assert np.median(d[np.isfinite(d)]) < 0.005


def test_deterministic(runs):
    _, a, b, _ = runs
    for f in ("trajectory.tum", "sparse.ply", "frames.csv"):
        assert (a.out_dir / f).read_bytes() == (b.out_dir / f).read_bytes(), f


def test_existing_output_refused(runs, tmp_path):
    data = runs[0]
    out = tmp_path / "taken"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(PipemapError):
        run_pipeline(data, out, load_settings())
    assert (out / "keep.txt").read_text() == "mine"


def test_cli_force_rule(runs, tmp_path):
    """run and evaluate refuse an existing output, replace it with --force, and never replace the dataset."""
    from typer.testing import CliRunner

    from pipemap.cli import app

    data = runs[0]
    runner = CliRunner()
    out = tmp_path / "taken"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    refused = runner.invoke(app, ["run", str(data), "--out", str(out), "--method", "network"])
    assert refused.exit_code != 0 and "already exists" in refused.output and (out / "keep.txt").exists()
    done = runner.invoke(app, ["run", str(data), "--out", str(out), "--method", "network", "--force"])
    assert done.exit_code == 0, done.output
    assert (out / "run.json").is_file() and not (out / "keep.txt").exists()
    assert runner.invoke(app, ["evaluate", str(out), str(data)]).exit_code == 0
    again = runner.invoke(app, ["evaluate", str(out), str(data)])
    assert again.exit_code != 0 and "metrics.json" in again.output and "--force" in again.output
    assert runner.invoke(app, ["evaluate", str(out), str(data), "--force"]).exit_code == 0
    own = runner.invoke(app, ["run", str(data), "--out", str(data), "--force"])
    assert own.exit_code != 0 and "would replace the input" in own.output
    assert (data / "dataset.yaml").is_file()


def test_sections_rated_and_strict_exit(runs, tmp_path):
    """The straight run is rated good from its own figures; limits no run can meet make it failed, which
    --strict turns into exit status 3 while the result folder is still written."""
    from typer.testing import CliRunner

    from pipemap.cli import app

    data, res, _, _ = runs
    q = json.loads((res.out_dir / "run.json").read_text())["quality"]
    assert q["rating"] == "good" and q["line"] == "map good: 1 section good" and q["gaps"] == []
    figures = q["sections"][0]["figures"]
    assert figures["free_radius_m"] == pytest.approx(0.2, rel=0.01)  # measured: 0.1 % off the 200 mm radius
    assert figures["rms_px"] < 0.5
    out = tmp_path / "strict"
    cli = CliRunner().invoke(app, ["run", str(data), "--out", str(out), "--method", "network", "--strict",
                                   "--set", "quality.rms_px=[0.001, 0.002]"])
    assert cli.exit_code == 3, cli.output
    assert "map failed: 1 section failed: section 0: reprojection RMS (px)" in " ".join(cli.output.split())
    assert (out / "run.json").exists()


def test_fixed_share_holds_the_oldest_part_of_the_overlap(runs, tmp_path):
    """straight_vo.fixed_share (0.5 by default): a window holds half the poses it shares with earlier solves
    rather than all of them, and the run stays metric (the newer half is solved again)."""
    data, res, _, _ = runs
    every = run_pipeline(data, tmp_path / "all", load_settings(overrides=["straight_vo.fixed_share=null"]))
    full = [w["fixed"] for w in json.loads((every.out_dir / "run.json").read_text())["windows"]]
    held = [w["fixed"] for w in json.loads((res.out_dir / "run.json").read_text())["windows"]]
    assert len(full) == len(held) >= 2 and max(full) > 2
    assert held == [max(int(round(0.5 * f)), 1) if f > 1 else f for f in full]
    m = evaluate(every.out_dir, data, write=False)
    assert abs(m.distance.forward.abs_error_pct) < 1.0


def test_a_recording_with_no_readable_frame_is_one_clear_line(tmp_path):
    """Every image damaged: `pipemap run` says so in one line, exits non-zero and writes no result folder."""
    from typer.testing import CliRunner

    from pipemap.cli import app

    data = tmp_path / "broken"
    (data / "images").mkdir(parents=True)
    for k in range(3):
        (data / "images" / f"{k:06d}.png").write_bytes(b"not a png")
    (data / "dataset.yaml").write_text("""format: pipemap-dataset/1
images: images/*.png
fps: 7.5
pipe: {radius_m: 0.15}
camera:
  model: pinhole
  width: 640
  height: 480
  params: {fx: 400, fy: 400, cx: 319.5, cy: 239.5, k1: 0, k2: 0, p1: 0, p2: 0, k3: 0}
""")
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["run", str(data), "--out", str(out)])
    assert res.exit_code != 0 and "no frame could be read" in res.output
    assert "Traceback" not in res.output and not out.exists()
