import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from pipemap.cli import app
from pipemap.config import Settings, load_settings
from pipemap.errors import PipemapError

runner = CliRunner()


def test_defaults_are_the_papers_values():
    s = Settings()
    assert s.frontend.regions == (2, 2) and s.frontend.corners_per_region == 200
    assert (s.bundle.window, s.bundle.step, s.bundle.tau) == (100, 50, 2.5e5)
    assert s.sparse.grid == (6, 8) and s.sparse.corners_per_cell == 20 and s.sparse.nms_px == 7
    assert (s.sparse.sigma_w, s.sparse.sigma_d, s.sparse.harris_k) == (3.0, 1.5, 0.04)
    from pipemap.mapping.appearance import colatitude_band
    from pipemap.sim.presets import fisheye_camera

    assert colatitude_band(s.appearance, fisheye_camera(640, 480)) == (50.0, 90.0)


def test_yaml_then_overrides(tmp_path):
    (tmp_path / "s.yaml").write_text("bundle:\n  tau: 1000.0\nseed: 3\n")
    s = load_settings(tmp_path / "s.yaml", ["bundle.window=40"])
    assert (s.bundle.tau, s.bundle.window, s.seed) == (1000.0, 40, 3)
    assert Settings.model_validate(s.to_dict()) == s


@pytest.mark.parametrize("override, words", [("bundle.nope=1", "bundle.nope"), ("bundle.tau=-1", "bundle.tau"),
                                             ("tau", "section.key=value")])
def test_bad_overrides(override, words):
    with pytest.raises(PipemapError, match=words):
        load_settings(None, [override])


def test_cli_help_for_every_command():
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    commands = [c.name or c.callback.__name__.replace("_", "-") for c in app.registered_commands]
    for name in commands:
        r = runner.invoke(app, [name, "--help"])
        assert r.exit_code == 0, name


def test_cli_error_is_one_line_and_nonzero(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "pipemap", "info", str(tmp_path / "nope")], capture_output=True,
                          text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "nope" in proc.stderr and "Traceback" not in proc.stderr


def test_settings_command_prints_yaml():
    r = runner.invoke(app, ["settings", "--set", "bundle.tau=5"])
    assert r.exit_code == 0 and yaml.safe_load(r.stdout)["bundle"]["tau"] == 5.0


def test_gain_mask_command(tmp_path):
    yy, xx = np.mgrid[0:48, 0:64]
    vignette = 200 * np.exp(-((xx - 32) ** 2 + (yy - 24) ** 2) / 2000.0)
    rng = np.random.default_rng(0)
    for i in range(4):
        cv2.imwrite(str(tmp_path / f"card{i}.png"),
                    np.clip(vignette + rng.normal(0, 3, vignette.shape), 0, 255).astype(np.uint8))
    out = tmp_path / "mask.png"
    r = runner.invoke(app, ["gain-mask", str(tmp_path / "card*.png"), "--out", str(out), "--sigma", "2"])
    assert r.exit_code == 0, r.output
    mask = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert mask.dtype == np.uint16 and mask.max() == 65535
    rel = mask / mask.max()
    np.testing.assert_allclose(rel, vignette / vignette.max(), atol=0.04)
    again = runner.invoke(app, ["gain-mask", str(tmp_path / "card*.png"), "--out", str(out)])
    assert again.exit_code == 2  # refuses to replace what the user has
