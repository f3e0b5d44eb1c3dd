"""`pipemap calibrate` end to end on rendered board images, including images it must skip."""

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from pipemap.camera import PolynomialCamera, load_camera
from pipemap.cli import app
from pipemap.sim.board import save_board_views


@pytest.fixture(scope="module")
def board_folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("calib")
    cam = PolynomialCamera(640, 480, dict(k1=145.0, k2=-1.0, k3=0.3, k4=-0.05, u0=320.4, v0=239.2), 95)
    save_board_views(root, cam, n_views=15, seed=1)
    (root / "images" / "zz_corrupt.png").write_bytes(b"not an image")
    return root, cam


def test_calibrate_command_recovers_the_camera(board_folder):
    root, truth = board_folder
    out = root / "est.yaml"
    result = CliRunner().invoke(app, ["calibrate", str(root / "images/*.png"), "--board", "9x6", "--square", "0.025",
                                      "--model", "polynomial", "--out", str(out), "--max-theta-deg", "95",
                                      "--folds", "3"])
    assert result.exit_code == 0, result.output
    assert ("zz_corrupt.png" in result.output and "RMS" in result.output
            and "held out in 3 folds" in " ".join(result.output.split()))
    cv = yaml.safe_load(out.read_text())["calibration"]["cross_validation"]
    assert cv["folds"] == 3 and cv["held_out_rms_px"] < 0.3
    est = load_camera(out)
    assert abs(est.params[0] / truth.params[0] - 1) < 0.01  # k1 within 1 %
    assert np.hypot(*(est.params[4:] - truth.params[4:])) < 1.0  # principal point within 1 px
    again = CliRunner().invoke(app, ["calibrate", str(root / "images/*.png"), "--out", str(out)])
    assert again.exit_code == 2 and "already exists" in again.output


@pytest.mark.parametrize("args, words", [(["--model", "fancy"], "unknown camera model"),
                                         (["--board", "nine"], "--board"), (["--folds", "1"], "--folds")])
def test_calibrate_bad_arguments(board_folder, tmp_path, args, words):
    root, _ = board_folder
    result = CliRunner().invoke(app, ["calibrate", str(root / "images/*.png"), "--out", str(tmp_path / "c.yaml"),
                                      *args])
    assert result.exit_code == 2 and words in result.output
