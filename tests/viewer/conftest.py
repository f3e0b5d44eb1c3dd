"""A small result folder with exact geometry, built once per session: the demo loop's first tee rendered
(60 frames, 320 x 240) and mapped with the appearance mapping at the true poses and pieces."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from viewer_helpers import ViewerCase

from pipemap.config import AppearanceSettings
from pipemap.dataset import load_dataset
from pipemap.mapping import WallPiece, write_maps
from pipemap.sim.simulate import simulate
from pipemap.trajectory import write_tum

LOOP = dict(width=320, height=240, frames=60, seed=0, spacing_m=0.02)
SEEN = ("S4.2", "S1.1")  # the pieces either side of T1 that the 60 frames see


@pytest.fixture(scope="session")
def viewer_case(tmp_path_factory) -> ViewerCase:
    base = tmp_path_factory.mktemp("viewer")
    ds = load_dataset(simulate("demo-loop", base / "data", **LOOP))
    net = ds.network()
    pieces = [WallPiece(s.id, s.start, s.end, net.radius_m, [0.0, 0.0, 1.0], True) for s in net.segments
              if s.id in SEEN]
    gt = ds.ground_truth_poses()
    result = base / "result"
    result.mkdir()
    write_tum(result / "trajectory.tum", gt)
    (result / "junctions.yaml").write_text(yaml.safe_dump({"format": "pipemap-junctions/2", "junctions": [
        {"id": j.id, "type": j.type, "centroid": j.centroid.tolist(), "keyframe": 0} for j in net.junctions[:1]]}))
    indices = np.rint(gt.timestamps * ds.fps).astype(int)
    info = write_maps(result, ds, indices, gt.matrices(), pieces, AppearanceSettings())
    run = {"format": "pipemap-run/2", "method": "network", "pipe_radius_m": net.radius_m,
           "quality": {"line": "map good: 2 sections good"}, "wall_pieces": [p.to_dict() for p in pieces],
           "appearance": info}
    (result / "run.json").write_text(json.dumps(run, default=float))
    return ViewerCase(result, pieces, net.radius_m)
