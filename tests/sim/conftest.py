"""Small simulator scenes and datasets, rendered once per test session (per xdist worker)."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.sim.network_model import straight_scene, tee_loop_scene
from pipemap.sim.simulate import simulate

LOOP_CORNERS = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [3.0, 2.0, 0.0], [0.0, 2.0, 0.0]])


@pytest.fixture(scope="session")
def loop_scene():
    """A tee loop with sagging, misaligned joints (the hard case for the union of cylinders)."""
    return tee_loop_scene(LOOP_CORNERS, 0.2, stub_length=0.5, piece_length=1.0, sag_m=0.004, misalign_m=0.003, seed=5)


@pytest.fixture(scope="session")
def straight():
    return straight_scene(4.0, 0.2, piece_length=2.0, sag_m=0.002, misalign_m=0.002, seed=1)


@pytest.fixture(scope="session")
def fisheye_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "fisheye"
    return simulate("fisheye-straight", out, width=160, height=120, frames=30, seed=3)


@pytest.fixture(scope="session")
def six_inch_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "six"
    return simulate("paper-straight-6in", out, width=160, height=120, frames=30, seed=4)
