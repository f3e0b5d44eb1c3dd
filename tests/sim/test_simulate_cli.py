"""`pipemap simulate` and `pipemap evaluate` together: ground truth scores zero, a 1 % scaled copy 1 %."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from pipemap.cli import app
from pipemap.dataset import load_dataset
from pipemap.trajectory import Trajectory, read_tum, write_tum

runner = CliRunner()


@pytest.fixture(scope="module")
def straight_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "fs"
    r = runner.invoke(app, ["simulate", "fisheye-straight", "--route", "forward-reverse", "--out", str(out),
                            "--width", "96", "--height", "72", "--spacing", "0.25"])
    assert r.exit_code == 0, r.output
    return out


def estimate(tmp_path, dataset, scale):
    gt = read_tum(dataset / "ground_truth" / "poses.tum")
    result = tmp_path / "result"
    result.mkdir()
    keyframes = np.arange(0, len(gt), 2)  # an estimate holds only keyframes
    write_tum(result / "trajectory.tum", Trajectory(gt.timestamps[keyframes], gt.positions[keyframes] * scale,
                                                    gt.rotations[keyframes]))
    return result


def test_simulated_dataset_loads(straight_run):
    ds = load_dataset(straight_run)
    assert len(ds) == len(read_tum(straight_run / "ground_truth/poses.tum")) > 20
    assert ds.network() is not None and len(ds.network().segments) == 3  # misaligned pieces


@pytest.mark.parametrize("scale", [1.0, 1.01])
def test_evaluate_ground_truth_and_scaled_copy(tmp_path, straight_run, scale):
    result = estimate(tmp_path, straight_run, scale)
    r = runner.invoke(app, ["evaluate", str(result), str(straight_run)])
    assert r.exit_code == 0, r.output
    m = json.loads((result / "metrics.json").read_text())
    expected = 100 * (scale - 1)
    assert m["path_length"]["error_pct"] == pytest.approx(expected, abs=1e-6)
    d = m["distance_travelled"]
    assert d["forward_and_reverse"]
    assert d["forward"]["abs_error_pct"] == pytest.approx(expected, abs=1e-4)  # own axis vs true axis
    assert d["reverse"]["abs_error_pct"] == pytest.approx(expected, abs=1e-4)
    assert m["ate"]["sim3"]["rmse_m"] < 1e-9
    if scale == 1.0:
        assert m["ate"]["rigid"]["rmse_m"] < 1e-9
    else:
        assert m["ate"]["rigid"]["rmse_m"] > 1e-3


def test_evaluate_missing_trajectory_is_one_line(tmp_path, straight_run):
    r = runner.invoke(app, ["evaluate", str(tmp_path), str(straight_run)])
    assert r.exit_code == 2 and "trajectory.tum" in r.output


def test_photo_texture_option_changes_the_wall(tmp_path):
    import cv2

    frames = {}
    for style in ("procedural", "brick"):
        r = runner.invoke(app, ["simulate", "fisheye-straight", "--out", str(tmp_path / style), "--width", "96",
                                "--height", "72", "--frames", "1", "--texture", style])
        assert r.exit_code == 0, r.output
        frames[style] = cv2.imread(str(tmp_path / style / "images/000000.png"), cv2.IMREAD_GRAYSCALE).astype(float)
    wall = frames["procedural"] > 10
    assert np.abs(frames["brick"] - frames["procedural"])[wall].mean() > 5
    bad = runner.invoke(app, ["simulate", "fisheye-straight", "--out", str(tmp_path / "x"), "--texture", "marble"])
    assert bad.exit_code == 2 and "marble" in bad.output and not (tmp_path / "x").exists()


def test_images_do_not_depend_on_the_number_of_workers(tmp_path):
    from pipemap.sim.simulate import simulate

    runs = [simulate("demo-loop", tmp_path / f"w{w}", width=96, height=72, frames=6, seed=2, workers=w) for w in (1, 2)]
    for a, b in zip(*(sorted((r / "images").glob("*.png")) for r in runs)):
        assert a.read_bytes() == b.read_bytes()


def test_specular_option_takes_the_highlight_off_the_wall(tmp_path):
    """`--specular 0` renders a matte wall: the highlight, where the wall faces the camera's light beside the robot
    (colatitude 80-95 deg), no longer brightens the rim against the wall further ahead (by about 16 % here)."""
    import cv2
    import yaml

    ratio = {}
    for name, args in (("preset", []), ("matte", ["--specular", "0"])):
        out = tmp_path / name
        r = runner.invoke(app, ["simulate", "fisheye-straight", "--out", str(out), "--width", "160", "--height", "120",
                                "--frames", "1", *args])
        assert r.exit_code == 0, r.output
        img = cv2.imread(str(out / "images/000000.png"), cv2.IMREAD_GRAYSCALE).astype(float)
        camera = load_dataset(out).camera
        v, u = np.mgrid[0:camera.height, 0:camera.width]
        bearings, _ = camera.unproject(np.stack([u.ravel(), v.ravel()], 1).astype(float))
        colatitude = np.degrees(np.arccos(np.clip(bearings.reshape(-1, 3)[:, 2], -1, 1))).reshape(img.shape)
        rim, ahead = (colatitude > 80) & (colatitude < 95), (colatitude > 30) & (colatitude < 60)
        ratio[name] = img[rim].mean() / img[ahead].mean()
        spec = yaml.safe_load((out / "ground_truth" / "simulation.yaml").read_text())["appearance"]["specular_strength"]
        assert spec == (0.0 if name == "matte" else 0.15)
    assert ratio["preset"] > 1.08 * ratio["matte"]
    bad = runner.invoke(app, ["simulate", "fisheye-straight", "--out", str(tmp_path / "x"), "--specular", "-1"])
    assert bad.exit_code == 2 and "highlight" in bad.output and not (tmp_path / "x").exists()
