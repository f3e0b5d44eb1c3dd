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


def test_a_bent_piece_round_trips_and_its_grid_follows_the_bend(tmp_path):
    from pipemap.mapping.wall import wall_grid

    d = {"name": "S1", "start": [0, 0, 0], "end": [2, 0, 0], "radius": 0.2, "up": [0, 0, 1],
         "bend": {"h": [0.0, 1.0, 2.0], "offset": [[0, 0, 0], [0.0005, 0, -0.002], [0, 0, 0]]}}
    (tmp_path / "run.json").write_text(json.dumps({"wall_pieces": [d]}))
    (piece,) = pieces_from_result(tmp_path)
    # The along-axis part of an offset is dropped: the bend is across the axis.
    assert np.allclose(piece.axis_offset([0.5, 1.0, 3.0]), [[0, 0, -0.001], [0, 0, -0.002], [0, 0, 0]])
    assert WallPiece.from_dict(piece.to_dict()).to_dict() == piece.to_dict()
    grid = wall_grid(piece, 0.01)
    P = grid.points()
    centre = P.mean(axis=1)  # the ring's centre at each h
    assert np.allclose(centre[:, 2], -0.002 * (1 - np.abs(grid.h - 1.0)), atol=1e-12)
    assert np.allclose(np.linalg.norm(P - centre[:, None], axis=2), 0.2, atol=1e-12)


@pytest.mark.parametrize("bend, problem", [
    ({"h": [0, 1]}, "bend must be"),
    ({"h": [0, 1], "offset": [[0, 0, 0]]}, "one [x, y, z] per h"),
    ({"h": [1, 0], "offset": [[0, 0, 0], [0, 0, 0]]}, "increasing"),
])
def test_a_bad_bend_names_the_file(tmp_path, bend, problem):
    d = {"name": "S1", "start": [0, 0, 0], "end": [2, 0, 0], "radius": 0.2, "up": [0, 0, 1], "bend": bend}
    (tmp_path / "run.json").write_text(json.dumps({"wall_pieces": [d]}))
    with pytest.raises(PipemapError, match="run.json") as info:
        pieces_from_result(tmp_path)
    assert problem in str(info.value)
