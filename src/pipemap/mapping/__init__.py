"""Maps of the pipe wall: the dense grey-level appearance point cloud and unrolled wall images."""

from pipemap.mapping.appearance import (
    AppearanceMap,
    PieceMap,
    build_appearance,
    read_appearance_ply,
    write_appearance_ply,
    write_appearance_ply_parts,
    write_maps,
)
from pipemap.mapping.elbow_piece import ElbowPiece, piece_from_dict, with_elbows
from pipemap.mapping.pieces import pieces_from_result
from pipemap.mapping.unrolled import read_unrolled, write_unrolled
from pipemap.mapping.wall import WallGrid, WallPiece, sample_wall, wall_grid

__all__ = ["AppearanceMap", "ElbowPiece", "PieceMap", "WallGrid", "WallPiece", "build_appearance", "piece_from_dict",
           "pieces_from_result", "read_appearance_ply", "read_unrolled", "sample_wall", "wall_grid",
           "write_appearance_ply", "write_appearance_ply_parts", "write_maps", "write_unrolled", "with_elbows"]
