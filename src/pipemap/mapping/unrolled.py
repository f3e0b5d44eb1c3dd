"""unrolled/<name>.png: the wall of each piece unrolled to (h, r*phi), with a JSON beside it.

Layout: columns run along the axis (h from start towards end; along an elbow's arc, the chainage along
its bent axis), rows run around the wall
starting at 12 o'clock and going anticlockwise when looking from start to end. That is the
wall as seen from inside the pipe, so lettering on it reads unmirrored; in the wall
coordinates of wall.py (phi clockwise) row k is phi = -k * 2 pi / rows. The JSON gives the
metres per pixel, the piece's axis and these conventions as numbers. Grey levels 1..255 are
the map's mean grey level; 0 marks wall that no keyframe saw.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import scipy.sparse as sp

from pipemap.errors import PipemapError
from pipemap.output import atomic_write_bytes, atomic_write_text

if TYPE_CHECKING:
    from pipemap.mapping.appearance import AppearanceMap, PieceMap

FORMAT = "pipemap-unrolled/3"
UNSEEN = 0
STRIP_COLUMNS = 1024  # image columns made at a time: 2 m of wall at 2 mm


def resample_weights(n_src: int, n_dst: int) -> sp.csr_matrix:
    """(n_dst, n_src) weights that resample n_src samples to n_dst along one axis, sample i at the centre of
    cell i of the same span: the overlap of the cells (box average, as cv2.INTER_AREA) when there are fewer, else
    linear between the nearest two (cv2.INTER_LINEAR's coordinates, clamped at the ends). Rows sum to 1."""
    scale = n_src / n_dst
    if n_dst < n_src:
        lo, hi = np.arange(n_dst) * scale, (np.arange(n_dst) + 1) * scale
        first = np.floor(lo).astype(np.int64)
        count = np.ceil(hi - 1e-9).astype(np.int64) - first
        row = np.repeat(np.arange(n_dst), count)
        col = np.repeat(first, count) + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        col = np.minimum(col, n_src - 1)
        w = np.clip(np.minimum(hi[row], col + 1.0) - np.maximum(lo[row], col), 0.0, None) / scale
    else:
        x = np.clip((np.arange(n_dst) + 0.5) * scale - 0.5, 0.0, n_src - 1)
        i0 = np.minimum(np.floor(x).astype(np.int64), n_src - 1)
        f = x - i0
        i1 = np.minimum(i0 + 1, n_src - 1)
        row = np.repeat(np.arange(n_dst), 2)
        col = np.column_stack([i0, i1]).ravel()
        w = np.column_stack([1.0 - f, f]).ravel()
    m = sp.csr_matrix((w, (row, col)), shape=(n_dst, n_src))
    m.eliminate_zeros()
    return m


def unrolled_image(pm: "PieceMap", px_m: float, chainage_of_start: float = 0.0) -> tuple[np.ndarray, dict]:
    """(rows, cols) uint8 image of one piece at about px_m metres per pixel, and its sidecar dict;
    `chainage_of_start`: the route's chainage at the piece's axis start (column 0). Grey levels are the
    seen grid points' means resampled to the image (area-weighted where it has fewer pixels than the grid,
    linear where more), STRIP_COLUMNS columns at a time: a 64 m piece whole had taken 450 MB."""
    piece = pm.piece
    values = pm.intensity  # (H along, W around)
    H, W = values.shape
    cols = max(2, int(round(piece.length / px_m)) + 1)
    rows = max(8, int(round(2 * np.pi * piece.radius / px_m)))
    around = resample_weights(W, rows)[:, (-np.arange(W)) % W]  # rows anticlockwise from 12 o'clock
    along = resample_weights(H, cols)
    img = np.full((rows, cols), UNSEEN, np.uint8)
    seen_pixels = 0
    for c0 in range(0, cols, STRIP_COLUMNS):
        strip = along[c0:c0 + STRIP_COLUMNS]
        used = np.unique(strip.indices)
        h0, h1 = int(used.min()), int(used.max()) + 1
        strip = strip[:, h0:h1]
        v = values[h0:h1]
        seen = np.isfinite(v)
        filled = around @ (strip @ np.where(seen, v, 0.0)).T  # (rows, strip columns)
        weight = around @ (strip @ seen.astype(np.float32)).T
        ok = weight > 0.5
        with np.errstate(invalid="ignore", divide="ignore"):
            grey = np.clip(np.rint(filled / weight), 1, 255)
        img[:, c0:c0 + strip.shape[0]] = np.where(ok, grey, UNSEEN).astype(np.uint8)
        seen_pixels += int(ok.sum())
    along_m = piece.length / (cols - 1)
    record = piece.to_dict()
    arc = {k: record[k] for k in ("centre", "normal", "bend_radius", "angle_deg")} if piece.kind == "arc" else None
    meta = unrolled_sidecar(piece.name, rows, cols, start=piece.start, end=piece.end, radius=piece.radius,
                            up=piece.up, px_m=px_m, along_m=along_m, phi_of_row_0=0.0,
                            phi_per_row=-2 * np.pi / rows, seen_fraction=seen_pixels / img.size,
                            bend=record.get("bend"), chainage_of_column_0=chainage_of_start, arc=arc)
    return img, meta


def unrolled_sidecar(piece: str, rows: int, cols: int, *, start, end, radius: float, up, px_m: float, along_m: float,
                     phi_of_row_0: float, phi_per_row: float, seen_fraction: float, bend: dict | None = None,
                     chainage_of_column_0: float = 0.0, arc: dict | None = None) -> dict:
    """The sidecar every method writes beside an unrolled image (`pipemap-unrolled/3`, docs/formats.md):
    columns run along the axis from `start` towards `end` (world frame of trajectory.tum), rows around the
    wall from `phi_of_row_0` in steps of `phi_per_row` (negative: anticlockwise looking from start to end,
    the wall as seen from inside), phi = 0 at `up` (12 o'clock); column 0 is at `chainage_of_column_0` on the
    route (route.json). `arc` ({centre, normal, bend_radius, angle_deg}): the axis is an elbow's arc from
    `start`, turning anticlockwise about `normal` (axis.kind `arc`; else `line`)."""
    return {
        "format": FORMAT,
        "piece": piece,
        "width_px": int(cols),
        "height_px": int(rows),
        "metres_per_pixel": float(px_m),
        "metres_per_pixel_along": float(along_m),
        "metres_per_pixel_around": float(abs(phi_per_row) * radius),
        "axis": {"kind": "line" if arc is None else "arc", "start": [float(v) for v in start],
                 "end": [float(v) for v in end], "radius": float(radius), "up": [float(v) for v in up],
                 **({"bend": bend} if bend is not None else {}), **(arc or {})},
        "frame": "world frame of trajectory.tum",
        "h_of_column_0_m": 0.0,
        "columns": "column c is at h = h_of_column_0_m + c * metres_per_pixel_along, metres along the axis from "
                   "start towards end (along an arc: along the bent axis)",
        "chainage_of_column_0_m": round(float(chainage_of_column_0), 6),
        "chainage": "column c is at chainage chainage_of_column_0_m + c * metres_per_pixel_along (route.json)",
        "clock_of_row_0_deg": float(np.degrees(phi_of_row_0) % 360.0),
        "clock_per_row_deg": float(np.degrees(phi_per_row)),
        "phi_of_row_0_rad": float(phi_of_row_0),
        "phi_per_row_rad": float(phi_per_row),
        "row_of_12_oclock": _row_of(0.0, phi_of_row_0, phi_per_row),
        "rows": "row k is at phi = phi_of_row_0_rad + k * phi_per_row_rad (mod 2 pi): rows go anticlockwise looking "
                "from start to end, so the image shows the wall as seen from inside the pipe",
        "phi_convention": "phi = 0 at 12 o'clock (axis.up across the axis), increasing clockwise looking from start "
                          "to end; the wall point is start + h u + b(h) + radius (cos(phi) e_up + sin(phi) "
                          "(u x e_up)), b(h) the axis's offset across u: linear between axis.bend.offset at "
                          "axis.bend.h, constant beyond its ends, zero without axis.bend; on an arc u and e_up "
                          "follow the local tangent (e_up: up across it) and start + h u is the arc's point at "
                          "h / bend_radius radians from start",
        "unseen_value": UNSEEN,
        "seen_fraction": float(seen_fraction),
    }


def _row_of(phi: float, phi_of_row_0: float, phi_per_row: float) -> float:
    """The (fractional) row at clock angle phi, the turn taken nearest the image's first row."""
    turn = 2 * np.pi
    d = ((phi - phi_of_row_0) / phi_per_row) % (turn / abs(phi_per_row))
    return float(d)


def _stem(name: str, used: set[str]) -> str:
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "piece"
    base, k = stem, 2
    while stem in used:
        stem = f"{base}-{k}"
        k += 1
    used.add(stem)
    return stem


def write_unrolled(folder: str | Path, appearance_map: "AppearanceMap", px_m: float | None = None,
                   chainage_of_start: dict | None = None) -> list[Path]:
    """unrolled/<name>.png and <name>.json for every piece with `unroll` that some keyframe saw;
    px_m defaults to the map's settings.unrolled_px_m; chainage_of_start: piece name -> chainage of its axis
    start (column 0; 0 where not given). Returns the PNG paths."""
    folder = Path(folder)
    px = float(px_m if px_m is not None else appearance_map.settings.unrolled_px_m)
    if not px > 0:
        raise PipemapError(f"metres per pixel must be positive, got {px}", key="appearance.unrolled_px_m")
    written: list[Path] = []
    used: set[str] = set()
    for pm in appearance_map.pieces:
        if not pm.piece.unroll or not pm.seen.any():
            continue
        folder.mkdir(parents=True, exist_ok=True)
        img, meta = unrolled_image(pm, px, (chainage_of_start or {}).get(pm.piece.name, 0.0))
        stem = _stem(pm.piece.name, used)
        ok, png = cv2.imencode(".png", img)
        if not ok:
            raise PipemapError("cannot encode image", folder / f"{stem}.png")
        meta["image"] = f"{stem}.png"
        atomic_write_bytes(folder / f"{stem}.png", png.tobytes())
        atomic_write_text(folder / f"{stem}.json", json.dumps(meta, indent=2) + "\n")
        written.append(folder / f"{stem}.png")
    return written


def read_unrolled(png: str | Path) -> tuple[np.ndarray, dict]:
    """An unrolled image and its sidecar."""
    png = Path(png)
    img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise PipemapError("cannot read image", png)
    side = png.with_suffix(".json")
    try:
        meta = json.loads(side.read_text())
    except FileNotFoundError:
        raise PipemapError("no JSON beside the unrolled image", side) from None
    except (OSError, ValueError) as exc:
        raise PipemapError(f"cannot read: {exc}", side) from None
    return img, meta


__all__ = ["write_unrolled", "read_unrolled", "unrolled_image", "resample_weights", "unrolled_sidecar", "FORMAT"]
