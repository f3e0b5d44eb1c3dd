"""Oval and dented pipe pieces: the ray caster's hits lie on the shaped wall to float precision, the
ellipse has the ovality asked for, and the ground truth records every shaped piece."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.errors import PipemapError
from pipemap.sim.network_model import Pipe, PipeScene
from pipemap.sim.presets import deformed_scene
from pipemap.sim.raycast import RayCaster
from pipemap.sim.wall_shape import Dent, WallShape, deformation_truth, shaped_lines


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-12), (np.float32, 2e-5)])
def test_hits_lie_on_the_shaped_wall(dtype, tol):
    scene = deformed_scene(scale=0.6)
    line = shaped_lines(scene)[0]
    caster = RayCaster(scene, dtype=dtype)
    rng = np.random.default_rng(3)
    d = rng.normal(size=(20000, 3))
    starts = np.array([p.start[0] for p in scene.pipes])
    for x in (0.9, 1.9, 2.6):  # in the 3 %, 6 % and dented pieces
        origin = np.array([x, 0.01, -0.04])
        hits = caster.cast_world(origin, d)
        wall = hits.hit & ~hits.cap
        P = origin + d / np.linalg.norm(d, axis=1)[:, None] * hits.t[:, None].astype(float)
        up, cw = P[:, 2], -P[:, 1]  # 12 o'clock = +z, 3 o'clock = axis x up = -y
        dev = line.deviation(P[:, 0] - line.origin[0], np.arctan2(cw, up), scene.radius)
        err = np.hypot(up, cw) - scene.radius - dev
        assert wall.mean() > 0.99
        assert np.abs(err[wall]).max() < tol
        assert np.abs(starts[hits.pipe[wall]] + hits.h[wall] - P[wall, 0]).max() < tol
        assert np.abs(dev[wall]).max() > 0.004  # the rays did meet the shapes


def test_ellipse_has_the_ovality_and_mean_diameter():
    shape = WallShape(6.0, 30.0)
    R = 0.15
    phi = np.linspace(0, np.pi, 1800, endpoint=False)
    D = 2 * R + shape.deviation(0.5, phi, R, 1.0) + shape.deviation(0.5, phi + np.pi, R, 1.0)
    assert (D.max() - D.min()) / ((D.max() + D.min()) / 2) * 100 == pytest.approx(6.0, abs=1e-6)
    assert np.degrees(phi[np.argmax(D)]) == pytest.approx(30.0, abs=0.1)
    assert shape.deviation(0.0, phi, R, 1.0) == pytest.approx(0.0, abs=1e-15)  # tapered to round at the joint


def test_dent_depth_and_extent():
    shape = WallShape(0.0, 0.0, (Dent(0.5, 330.0, 0.01, 0.3, 60.0),))
    R = 0.15
    assert shape.deviation(0.5, np.radians(330.0), R, 1.0) == pytest.approx(-0.01)
    assert shape.deviation(0.5, np.radians(270.0), R, 1.0) == pytest.approx(0.0)
    assert shape.deviation(0.66, np.radians(330.0), R, 1.0) == pytest.approx(0.0)


def test_truth_lists_shaped_pieces_and_bad_shapes_fail():
    truth = deformation_truth(deformed_scene())
    assert [p["ovality_pct"] for p in truth["pieces"]] == [3.0, 6.0, 0.0]
    assert truth["pieces"][2]["dents"][0]["depth_m"] == 0.01
    bad = Pipe("S1", np.zeros(3), np.array([0.5, 0, 0]), shape=WallShape(0.0, 0.0, (Dent(0.45, 0.0, 0.01, 0.3),)))
    with pytest.raises(PipemapError, match="reaches beyond the piece"):
        RayCaster(PipeScene(0.15, (bad,)))
