"""The unrolled walls of a result (unrolled/*.png and their sidecars) in the inspector's coordinates.

A column is a distance along the pipe: chainage where the sidecar gives `chainage_of_column_0_m`
(`pipemap-unrolled/2`, `/3`), else h from the piece's `axis.start` (`/1`); `/3` adds elbows, whose
columns run along the arc of their axis. A row is a clock position:
phi = phi_of_row_0_rad + row * phi_per_row_rad, 0 at 12 o'clock, clockwise looking along the survey.
Pixel coordinates have their origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import base64
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipemap.errors import PipemapError
from pipemap.mapping.elbow_piece import ElbowPiece, piece_from_dict
from pipemap.mapping.wall import WallPiece

# An observation's wall point is placed on the unrolled wall of the piece it lies on: within the image's
# length and at most this fraction of the radius off the wall (a point seen through a tee's opening lies far
# off the piece it looks out of).
OFF_WALL_RADII = 0.25


@dataclass(frozen=True)
class UnrolledWall:
    name: str
    png: Path
    width: int
    height: int
    h0_m: float  # h of column 0 from axis.start
    along_per_px: float
    chainage0_m: float | None  # chainage of column 0 (None: the sidecar has none)
    phi0_rad: float
    phi_per_row_rad: float
    piece: WallPiece | ElbowPiece  # the axis the image is unrolled about (an elbow's: its arc)

    @classmethod
    def from_sidecar(cls, png: Path) -> "UnrolledWall":
        side = png.with_suffix(".json")
        try:
            meta = json.loads(side.read_text())
        except FileNotFoundError:
            raise PipemapError("no JSON beside the unrolled image", side) from None
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise PipemapError(f"cannot read: {exc}", side) from None
        if not isinstance(meta, dict) or not str(meta.get("format", "")).startswith("pipemap-unrolled/"):
            raise PipemapError("not a pipemap-unrolled sidecar (no format: pipemap-unrolled/N)", side)
        try:
            axis = meta["axis"]
            piece = piece_from_dict({"name": meta.get("piece", png.stem), **axis}, str(side))
            chainage0 = meta.get("chainage_of_column_0_m")
            return cls(str(meta.get("piece", png.stem)), png, int(meta["width_px"]), int(meta["height_px"]),
                       float(meta.get("h_of_column_0_m", 0.0)), float(meta["metres_per_pixel_along"]),
                       None if chainage0 is None else float(chainage0), float(meta["phi_of_row_0_rad"]),
                       float(meta["phi_per_row_rad"]), piece)
        except KeyError as exc:
            raise PipemapError(f"missing {exc.args[0]}", side) from None
        except (TypeError, ValueError) as exc:
            raise PipemapError(f"not a number: {exc}", side) from None

    @property
    def rows_per_turn(self) -> float:
        return 2 * math.pi / abs(self.phi_per_row_rad)

    def along_of_column(self, col):
        """Chainage (or h, without chainage) of column `col`."""
        base = self.h0_m if self.chainage0_m is None else self.chainage0_m
        return base + np.asarray(col, float) * self.along_per_px

    def clock_deg_of_row(self, row):
        return np.mod(np.degrees(self.phi0_rad + np.asarray(row, float) * self.phi_per_row_rad), 360.0)

    def row_of_clock(self, clock_deg):
        d = (np.radians(np.asarray(clock_deg, float)) - self.phi0_rad) / self.phi_per_row_rad
        return np.mod(d, self.rows_per_turn)

    def column_of_chainage(self, chainage_m):
        return (np.asarray(chainage_m, float) - self.chainage0_m) / self.along_per_px

    def place(self, xyz) -> tuple[float, float, float]:
        """(column, row, distance off the wall in radii) of a world point."""
        h, phi, rho = self.piece.wall_coordinates(np.asarray(xyz, float))
        col = (float(h) - self.h0_m) / self.along_per_px
        row = float(self.row_of_clock(np.degrees(phi)))
        return col, row, abs(float(rho) - self.piece.radius) / self.piece.radius

    def data_uri(self) -> str:
        """The PNG as a data: URI."""
        try:
            png = self.png.read_bytes()
        except OSError as exc:
            raise PipemapError(f"cannot read: {exc}", self.png) from None
        if not png.startswith(b"\x89PNG"):
            raise PipemapError("not a PNG image", self.png)
        return "data:image/png;base64," + base64.b64encode(png).decode("ascii")

    def page_data(self, index: int) -> dict:
        """What the page needs to draw the wall: its image element and the two axes' coordinates."""
        chainage = self.chainage0_m is not None
        return {"name": self.name, "image": f"wall-image-{index}", "cols": self.width, "rows": self.height,
                "along0": float(self.along_of_column(0)),
                "alongPx": self.along_per_px, "alongKind": "chainage" if chainage else "h",
                "phi0Deg": math.degrees(self.phi0_rad), "phiPerRowDeg": math.degrees(self.phi_per_row_rad)}


def read_walls(result_dir: Path) -> list[UnrolledWall]:
    folder = Path(result_dir) / "unrolled"
    if not folder.is_dir():
        return []
    walls = [UnrolledWall.from_sidecar(png) for png in sorted(folder.glob("*.png"))]
    # in route order where the sidecars carry chainage (an elbow's wall between the pipes either side of it)
    return sorted(walls, key=lambda w: (w.chainage0_m is None, w.chainage0_m or 0.0, w.name))


def place_observation(obs: dict, walls: list[UnrolledWall]) -> dict | None:
    """Where an observation's marker goes: {wall, col, row, col2, row2} (col2, row2: the far corner of a
    stretch or a clock span; equal to col, row for a point), or None when it lies on no unrolled wall. Its
    wall point (x, y, z) picks the wall; without one, its section and chainage do, where the walls carry
    chainage. On a wall with chainage the marker starts at chainage_m and clock_from_deg."""
    start = _start(obs, walls)
    if start is None:
        return None
    wall, col, row = start
    if wall.chainage0_m is not None and obs.get("chainage_m") is not None and obs.get("clock_from_deg") is not None:
        # x, y, z of a box is its centre; its chainage and clock spans start at chainage_m and clock_from_deg
        col, row = float(wall.column_of_chainage(obs["chainage_m"])), float(wall.row_of_clock(obs["clock_from_deg"]))
    col2, row2 = col, row
    if obs.get("chainage_to_m") is not None and obs.get("chainage_m") is not None:
        col2 = col + (obs["chainage_to_m"] - obs["chainage_m"]) / wall.along_per_px
    if obs.get("clock_to_deg") is not None and obs.get("clock_from_deg") is not None:
        span = (obs["clock_to_deg"] - obs["clock_from_deg"]) % 360.0
        row2 = row + math.radians(span) / wall.phi_per_row_rad
    return {"wall": wall.name, "col": col, "row": row, "col2": col2, "row2": row2}


def _start(obs: dict, walls: list[UnrolledWall]):
    xyz = [obs.get(k) for k in ("x", "y", "z")]
    if all(v is not None for v in xyz):
        best = None
        for wall in walls:
            col, row, off = wall.place(xyz)
            if -0.5 <= col <= wall.width - 0.5 and off <= OFF_WALL_RADII and (best is None or off < best[0]):
                best = (off, wall, col, row)
        if best is not None:
            return best[1:]
    chainage, clock = obs.get("chainage_m"), obs.get("clock_from_deg")
    if chainage is None or clock is None:
        return None
    section = str(obs.get("section") or "")
    for wall in sorted(walls, key=lambda w: w.name != section):
        if wall.chainage0_m is None:
            continue
        col = float(wall.column_of_chainage(chainage))
        if wall.name == section or -0.5 <= col <= wall.width - 0.5:
            return wall, col, float(wall.row_of_clock(clock))
    return None


__all__ = ["UnrolledWall", "read_walls", "place_observation", "OFF_WALL_RADII"]
