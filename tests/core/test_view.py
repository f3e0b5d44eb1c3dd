"""Which way the camera looks (`pipemap run --method auto`) and whether it sees enough of the wall."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pipemap.dataset import load_dataset
from pipemap.errors import PipemapError
from pipemap.frontend.tracks import Keyframe
from pipemap.geometry.rotations import exp_so3
from pipemap.sim.presets import cctv_camera, perspective_camera
from pipemap.view import WALL, WALL_METHOD, camera_view, check_wall_in_view, travel_direction


def _keyframes(direction, rotation_deg, n=5, seed=0):
    """Keyframes stepping 2 cm along `direction` (camera axes) past random points, rotating a little each step."""
    rng = np.random.default_rng(seed)
    X = rng.uniform([-0.3, -0.3, 0.2], [0.3, 0.3, 0.6], (300, 3))  # a pipe wall a few decimetres off
    R, c = np.eye(3), np.zeros(3)
    out = []
    for k in range(n):
        if k:
            dR = exp_so3(np.radians(rotation_deg) * rng.standard_normal(3))
            R, c = R @ dR, c + 0.02 * R @ direction
        Xc = (X - c) @ R
        b = Xc / np.linalg.norm(Xc, axis=1, keepdims=True)
        ids = np.arange(len(X))
        out.append(Keyframe(k, k, k / 10, np.zeros((len(X), 2)), b, ids, np.full(len(X), k > 0), np.zeros(len(X), bool),
                            np.eye(3), np.array([0, 0, 1.0]), k > 0))
    return out


@pytest.mark.parametrize("angle", [0.0, 50.0, 75.0, 90.0])
def test_line_of_travel_from_epipolar_planes(angle):
    a = np.radians(angle)
    d = np.array([np.sin(a), 0.0, np.cos(a)])
    est, steps = travel_direction(_keyframes(d, rotation_deg=0.05))
    assert steps == 4
    # a robot turning 0.05 deg between keyframes biases the line by about a degree at most
    assert np.degrees(np.arccos(min(1.0, abs(est @ d)))) < 1.0


def test_too_little_wall_in_view_is_one_clear_error(tmp_path):
    narrow = SimpleNamespace(camera=perspective_camera(640, 480, 30.0, -0.05, 0.0), yaml_path=tmp_path / "dataset.yaml")
    with pytest.raises(PipemapError, match="sees too little of the pipe wall"):
        check_wall_in_view(narrow)
    check_wall_in_view(SimpleNamespace(camera=cctv_camera(), yaml_path=tmp_path / "dataset.yaml"))


def test_auto_sends_an_oblique_wall_camera_to_the_straight_pipe_methods(tmp_path):
    from pipemap.sim.simulate import simulate

    data = simulate("wall-camera-50", tmp_path / "w50", width=320, height=240, frames=30, seed=1)
    view = camera_view(load_dataset(data))
    assert view.looks == WALL and view.method == WALL_METHOD
    assert view.travel_deg == pytest.approx(50.0, abs=3.0)  # the mount, give or take the robot's 1 deg wobble
