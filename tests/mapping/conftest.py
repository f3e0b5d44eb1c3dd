"""A small tee-loop render and its ground-truth appearance map, built once per session."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from pipemap.config import AppearanceSettings
from pipemap.dataset import Dataset, load_dataset
from pipemap.mapping import AppearanceMap, WallPiece, build_appearance
from pipemap.sim.simulate import plan, simulate
from pipemap.sim.texture import WallTexture

# demo-loop through its first tee (T1 at the origin): 60 frames 2 cm apart, 320 x 240
LOOP = dict(preset="demo-loop", width=320, height=240, frames=60, seed=0, spacing_m=0.02)


@dataclass
class LoopCase:
    dataset: Dataset
    pieces: list[WallPiece]
    scene: object  # the simulator's PipeScene (pieces with their joint overlaps)
    texture: WallTexture
    indices: np.ndarray
    poses: np.ndarray  # (N, 4, 4) true T_wc


def ground_truth_pieces(dataset: Dataset) -> list[WallPiece]:
    net = dataset.network()
    return [WallPiece(s.id, s.start, s.end, net.radius_m, [0.0, 0.0, 1.0], not s.id.startswith("B"))
            for s in net.segments]


@pytest.fixture(scope="session")
def loop_case(tmp_path_factory) -> LoopCase:
    kw = dict(LOOP)
    preset = kw.pop("preset")
    root = simulate(preset, tmp_path_factory.mktemp("mapping") / "loop", **kw)
    ds = load_dataset(root)
    setup = plan(preset, **kw).setup
    gt = ds.ground_truth_poses()
    return LoopCase(ds, ground_truth_pieces(ds), setup.scene,
                    WallTexture(LOOP["seed"], setup.appearance.mm_per_px, setup.appearance.texture_style),
                    np.arange(len(gt)), gt.matrices())


@pytest.fixture(scope="session")
def loop_map(loop_case) -> AppearanceMap:
    c = loop_case
    return build_appearance(c.dataset, c.indices, c.poses, c.pieces, AppearanceSettings())


@pytest.fixture(scope="session")
def deformed_run(tmp_path_factory):
    """The deformed-pipe preset's tiny route (pieces 0.4 m; a 3 % and a 6 % oval piece, a 10 mm dent) at
    480 x 360, a frame every 2.5 cm, through `pipemap run`: (dataset, result folder)."""
    from pipemap.config import load_settings
    from pipemap.pipeline import run_pipeline

    base = tmp_path_factory.mktemp("deformed")
    data = simulate("deformed-pipe", base / "data", route="tiny", width=480, height=360, spacing_m=0.025, seed=0)
    run_pipeline(data, base / "out", load_settings())
    return data, base / "out"
