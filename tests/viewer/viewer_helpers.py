"""Helpers of the viewer tests: exact wall points, copies of the session's result, contract-shaped tables."""

from __future__ import annotations

import csv
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipemap.mapping import WallPiece
from pipemap.viewer.tables import DEFORMATION_COLUMNS, OBSERVATION_COLUMNS


@dataclass
class ViewerCase:
    result: Path  # pipemap-unrolled/1 sidecars, no deformation or observations
    pieces: list[WallPiece]
    radius: float


def wall_point(piece: WallPiece, h: float, clock_deg: float) -> np.ndarray:
    """The point of a straight piece's wall at h from its start and a clock position (docs/formats.md)."""
    u, e_up, e_cw = piece.frame()
    a = np.radians(clock_deg)
    return piece.start + h * u + piece.radius * (np.cos(a) * e_up + np.sin(a) * e_cw)


def copy_result(case: ViewerCase, dest: Path, chainage_of: dict[str, float] | None = None) -> Path:
    """A copy of the case's result; `chainage_of` {piece: chainage of column 0} makes its sidecars
    pipemap-unrolled/2 as the route's chainage writes them, the others pipemap-unrolled/1 (no chainage)."""
    shutil.copytree(case.result, dest)
    for side in (dest / "unrolled").glob("*.json"):
        meta = json.loads(side.read_text())
        if chainage_of and meta["piece"] in chainage_of:
            meta["format"] = "pipemap-unrolled/2"
            meta["chainage_of_column_0_m"] = chainage_of[meta["piece"]]
        else:
            meta["format"] = "pipemap-unrolled/1"
            meta.pop("chainage_of_column_0_m", None)
            meta.pop("chainage", None)
        side.write_text(json.dumps(meta))
    return dest


def write_csv(path: Path, columns, rows: list[dict]) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(columns))
        w.writeheader()
        for r in rows:
            w.writerow({k: "" if r.get(k) is None else r[k] for k in columns})
    return path


def deformation_rows(pieces: list[WallPiece], chainage0: dict[str, float] | None) -> list[dict]:
    """Every 10 cm of each piece, both sources: ovality 1 % + 0.5 % per metre, a 4 mm dent at 0.3 m."""
    rows = []
    for p in pieces:
        for h in np.arange(0.05, p.length, 0.1):
            for source in ("sparse", "dense"):
                ov = 1.0 + 0.5 * h
                d = 2 * p.radius
                rows.append({"piece": p.name, "chainage_m": None if chainage0 is None else chainage0[p.name] + h,
                             "h_m": round(h, 3), "source": source, "points": 500, "diameter_x_m": d * (1 + ov / 200),
                             "diameter_y_m": d * (1 - ov / 200), "diameter_min_m": d * (1 - ov / 200),
                             "diameter_max_m": d * (1 + ov / 200), "ovality_pct": round(ov, 3),
                             "max_inward_m": 0.004 if abs(h - 0.35) < 0.06 else 0.0005, "max_outward_m": 0.0005})
    return rows


def observation_rows(pieces: list[WallPiece], chainage0: dict[str, float] | None) -> list[dict]:
    """A point on each piece and a circumferential crack over 1 to 4 o'clock on the first, placed by their
    wall points (x, y, z) and, where the pieces carry it, chainage."""
    out = []
    for i, (p, h, clock) in enumerate([(pieces[0], 0.4, 135.0), (pieces[1], 0.25, 300.0)]):
        x = wall_point(p, h, clock)
        out.append({"id": f"O{i + 1}", "frame": 10 + i, "u": 100, "v": 120, "code": "DAM", "remark": "deposit",
                    "section": p.name, "chainage_m": None if chainage0 is None else chainage0[p.name] + h,
                    "clock_from_deg": clock, "x": x[0], "y": x[1], "z": x[2], "image": f"frame_{10 + i}.png"})
    p, h = pieces[0], 0.2
    x = wall_point(p, h, 30.0)
    out.append({"id": "O3", "frame": 20, "u": 50, "v": 60, "u2": 90, "v2": 80, "code": "CC", "remark": "crack",
                "continuous": "start", "section": p.name, "chainage_m": None if chainage0 is None else chainage0[p.name]
                + h, "chainage_to_m": None if chainage0 is None else chainage0[p.name] + h + 0.1,
                "clock_from_deg": 30.0, "clock_to_deg": 120.0, "x": x[0], "y": x[1], "z": x[2]})
    return out


__all__ = ["ViewerCase", "copy_result", "write_csv", "deformation_rows", "observation_rows", "wall_point",
           "DEFORMATION_COLUMNS", "OBSERVATION_COLUMNS"]
