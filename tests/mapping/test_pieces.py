"""Wall pieces read from a result folder's run.json."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipemap.errors import PipemapError
from pipemap.mapping import WallPiece, pieces_from_result
from pipemap.trajectory import Trajectory, write_tum


def test_wall_pieces_from_run_json(tmp_path):
    pieces = [WallPiece("S1", [0, 0, 0], [2.0, 0, 0], 0.2, [0, 0, 1.0]),
              WallPiece("T1-branch", [2.0, 0, 0], [2.0, 0.4, 0], 0.2, [0, 0, 1.0], unroll=False)]
    (tmp_path / "run.json").write_text(json.dumps({"wall_pieces": [p.to_dict() for p in pieces]}))
    back = pieces_from_result(tmp_path)
    assert [p.name for p in back] == ["S1", "T1-branch"] and [p.unroll for p in back] == [True, False]
    np.testing.assert_array_equal(back[1].end, [2.0, 0.4, 0])


def test_bad_wall_pieces_name_the_file(tmp_path):
    (tmp_path / "run.json").write_text(json.dumps({"wall_pieces": [{"name": "S1", "start": [0, 0, 0]}]}))
    with pytest.raises(PipemapError, match=r"run.json: wall_pieces\[0\]: missing end, radius, up"):
        pieces_from_result(tmp_path)
    with pytest.raises(PipemapError, match="no run.json"):
        pieces_from_result(tmp_path / "nowhere")


def test_pieces_derived_from_straight_sections(tmp_path):
    # camera frame: z forward along the pipe, y down; the pipe runs along world +z
    n = 11
    R = np.tile(np.eye(3), (n, 1, 1))
    c = np.stack([np.zeros(n), np.full(n, 0.04), np.linspace(0, 1, n)], axis=1)
    write_tum(tmp_path / "trajectory.tum", Trajectory(np.arange(n) / 7.5, c, R))
    section = {"first_keyframe": 0, "last_keyframe": n - 1,
               "cylinder": {"origin": [0, 0, 5.0], "direction": [0, 0, -1.0], "radius": 0.2}}
    (tmp_path / "run.json").write_text(json.dumps({"straight_sections": [section, {"cylinder": None}]}))
    (piece,) = pieces_from_result(tmp_path)
    np.testing.assert_allclose(piece.start, [0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(piece.end, [0, 0, 1.0 + 0.2 / np.tan(np.radians(50))], atol=1e-12)
    np.testing.assert_allclose(piece.frame()[1], [0, -1.0, 0], atol=1e-12)  # 12 o'clock = image up
