"""Renders of the 2010 report's pipes shared by the straight-pipe tests, made once per session."""

from __future__ import annotations

import shutil

import pytest

from pipemap.config import Settings
from pipemap.sim.simulate import simulate


def _with_gain_mask(ds, card):
    shutil.copy(card / "gain_mask.png", ds / "gain_mask.png")
    with open(ds / "dataset.yaml", "a") as fh:
        fh.write("gain_mask: gain_mask.png\n")
    return ds


@pytest.fixture(scope="session")
def six_inch_sparse(tmp_path_factory):
    """80 frames of the 6-inch forward route at 320x240, 3 mm apart (about 7 px of flow per frame),
    with the white-card gain mask of the same camera (report section 3.2)."""
    root = tmp_path_factory.mktemp("sparse6")
    card = simulate("white-card", root / "card", width=320, height=240, seed=1)
    ds = simulate("paper-straight-6in", root / "six", width=320, height=240, frames=80, seed=1, route="forward",
                  spacing_m=0.003, workers=1)
    return _with_gain_mask(ds, card)



@pytest.fixture(scope="session")
def six_inch_sparse_result(six_inch_sparse, tmp_path_factory):
    """run_sparse with its default settings on the 6-inch render: (result folder, SparseResult)."""
    from pipemap.straight.sparse.run import run_sparse

    out = tmp_path_factory.mktemp("sparse-result") / "res"
    return out, run_sparse(six_inch_sparse, out)


@pytest.fixture(scope="session")
def sixteen_inch_sparse(tmp_path_factory):
    """80 frames of the 16-inch forward route at 320x240 (25 deg lens, camera 70 mm below the axis),
    2 mm apart (about 5 px of flow per frame), with the white-card gain mask of the same camera."""
    root = tmp_path_factory.mktemp("sparse16")
    card = simulate("white-card", root / "card", width=320, height=240, seed=1, route="16in")
    ds = simulate("paper-straight-16in", root / "sixteen", width=320, height=240, frames=80, seed=1, route="forward",
                  spacing_m=0.002, workers=1)
    return _with_gain_mask(ds, card)


@pytest.fixture(scope="session")
def oblique_wall(tmp_path_factory):
    """200 frames (1 m, forward) at 480x360 of the wall camera turned to 50 deg from the pipe axis: 3 cm beside and
    4 cm below the axis of a 387.56 mm pipe, no gain mask, the robot wobbling up to 1 deg and 3 mm."""
    root = tmp_path_factory.mktemp("oblique")
    return simulate("wall-camera-50", root / "w50", width=480, height=360, frames=200, seed=1, route="forward",
                    workers=2)


def short_run() -> Settings:
    """The oblique render is 1 m long: the long batch over 40 keyframes (every third) instead of 100."""
    s = Settings()
    s.sparse.offset_long_keyframes = 40
    return s


@pytest.fixture(scope="session")
def oblique_dense(oblique_wall, tmp_path_factory):
    """dense-hybrid at its defaults (no reference, no offset) on the oblique render: (result folder, DenseResult)."""
    from pipemap.straight.dense import run_dense

    out = tmp_path_factory.mktemp("oblique-dense") / "res"
    return out, run_dense(oblique_wall, out, short_run(), "dense-hybrid")
