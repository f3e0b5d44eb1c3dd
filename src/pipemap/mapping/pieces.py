"""The wall pieces of a result folder: run.json "wall_pieces" (what the pipeline records), or,
for results written before it did, pieces derived from run.json "straight_sections" and
trajectory.tum."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from pipemap.errors import PipemapError
from pipemap.mapping.elbow_piece import ElbowPiece, piece_from_dict
from pipemap.mapping.wall import WallPiece
from pipemap.trajectory import read_tum

# A derived piece reaches this far past its last camera centre: the wall ahead of the camera
# that the 50 deg colatitude limit of the appearance map still sees, r / tan(50 deg).
AHEAD_RADII = 1.0 / math.tan(math.radians(50.0))


def read_run(result_dir: Path) -> dict:
    path = Path(result_dir) / "run.json"
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise PipemapError("no run.json in the result folder", path) from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise PipemapError(f"cannot read: {exc}", path) from None
    if not isinstance(data, dict):
        raise PipemapError("expected a JSON object", path)
    return data


def pieces_from_result(result_dir: str | Path) -> list[WallPiece | ElbowPiece]:
    """The result's wall pieces: run.json "wall_pieces" (a list of {name, start, end, radius, up,
    unroll}, elbows with kind "arc"); without it, one piece per fitted straight section. [] when neither is there."""
    result_dir = Path(result_dir)
    run = read_run(result_dir)
    where = result_dir / "run.json"
    if "wall_pieces" in run:
        items = run["wall_pieces"]
        if not isinstance(items, list):
            raise PipemapError("wall_pieces must be a list", where)
        return [piece_from_dict(d, f"{where}: wall_pieces[{i}]") for i, d in enumerate(items)]
    sections = run.get("straight_sections") or []
    traj_path = result_dir / "trajectory.tum"
    if not sections or not traj_path.exists():
        return []
    return pieces_from_sections(sections, read_tum(traj_path))


def pieces_from_sections(sections: list[dict], trajectory) -> list[WallPiece]:
    """One piece per straight section with a fitted cylinder: the axis oriented along the camera's
    travel, from its first camera centre to AHEAD_RADII radii past its last, 12 o'clock opposite
    the cameras' mean image-down direction (camera y)."""
    pieces = []
    for s in sections:
        cyl = s.get("cylinder") if isinstance(s, dict) else None
        if not cyl:
            continue
        a, b = int(s["first_keyframe"]), int(s["last_keyframe"])
        if not (0 <= a < b < len(trajectory)):
            continue
        origin = np.asarray(cyl["origin"], float)
        u = np.asarray(cyl["direction"], float)
        u = u / np.linalg.norm(u)
        radius = float(cyl["radius"])
        centres = trajectory.positions[a:b + 1]
        if (centres[-1] - centres[0]) @ u < 0:
            u = -u
        h = (centres - origin) @ u
        h0, h1 = float(h.min()), float(h.max()) + AHEAD_RADII * radius
        up = -trajectory.rotations[a:b + 1, :, 1].mean(axis=0)
        pieces.append(WallPiece(f"S{len(pieces) + 1}", origin + h0 * u, origin + h1 * u, radius, up, True))
    return pieces


__all__ = ["pieces_from_result", "pieces_from_sections", "read_run"]
