"""Deformation of the straight pieces: ovality, X/Y diameters and the largest inward and outward deviation
(a dent) every `slice_m` along each piece, as laser profilers report them (ASTM F3080: every 10 cm).

Per slice, the wall points near it are taken in the piece's wall coordinates (h, phi clockwise from 12
o'clock, distance from the bent axis) and r(phi) is fitted as a Fourier series of `harmonics` terms by
least squares, dropping points more than `outlier_mads` MADs off. The diameter in direction phi is
D(phi) = r(phi) + r(phi + pi) (odd terms, a centre offset among them, cancel), so:

- diameter_y (vertical: 12 to 6 o'clock) = D(0), diameter_x (horizontal: 3 to 9 o'clock) = D(pi/2);
- diameter_min / diameter_max = the least and greatest D(phi); ovality % = (Dmax - Dmin) / Dmean * 100 with
  Dmean the mean of D(phi) over all directions (for an ellipse, twice ASTM F1216's (Dmean - Dmin) / Dmean);
- max_inward / max_outward: the largest deviation below / above the a-priori radius of the median radius in
  cells of `bin_deg` around by `dent_cell_m` along within the slice's band, after the fitted centre offset
  (first harmonic) is taken out: the deepest point of the slice's stretch of wall, so that a dent between
  two slice positions is not missed.
"""

from __future__ import annotations

import csv
import io
from dataclasses import asdict, dataclass

import numpy as np

from pipemap.config import DeformationSettings
from pipemap.mapping.wall import WallPiece

COLUMNS = ("piece", "chainage_m", "h_m", "source", "points", "diameter_x_m", "diameter_y_m", "diameter_min_m",
           "diameter_max_m", "ovality_pct", "max_inward_m", "max_outward_m")


@dataclass(frozen=True)
class SliceProfile:
    """One slice of one piece from one source (a row of deformation.csv)."""

    piece: str
    h_m: float
    source: str  # sparse | dense
    points: int
    diameter_x_m: float
    diameter_y_m: float
    diameter_min_m: float
    diameter_max_m: float
    ovality_pct: float
    max_inward_m: float
    max_outward_m: float
    chainage_m: float | None = None


def wall_samples(piece: WallPiece, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(h, phi, r) of world points about the piece's (bent) axis."""
    h, _, _ = piece.wall_coordinates(points)
    return piece.wall_coordinates(np.asarray(points, float) - piece.axis_offset(h))


def profile(h_c: float, phi: np.ndarray, r: np.ndarray, radius: float, s: DeformationSettings, piece: str,
            source: str, h: np.ndarray | None = None) -> SliceProfile | None:
    """The slice at h_c from its points' phi, r and h (None: a ring; too few points, or they leave the
    circle open: None)."""
    bins = np.floor(np.mod(phi, 2 * np.pi) / np.radians(10.0)).astype(int)
    keep = np.isfinite(r)
    for _ in range(3):
        if keep.sum() < s.min_points or 10.0 * len(np.unique(bins[keep])) < s.min_cover_deg:
            return None
        coef = np.linalg.lstsq(_basis(phi[keep], s.harmonics), r[keep], rcond=None)[0]
        res = r - _basis(phi, s.harmonics) @ coef
        mad = 1.4826 * np.median(np.abs(res[keep])) + 1e-6
        new = np.isfinite(r) & (np.abs(res) <= s.outlier_mads * mad)
        if np.array_equal(new, keep):
            break
        keep = new
    grid = np.linspace(0.0, np.pi, 360, endpoint=False)
    D = _basis(grid, s.harmonics) @ coef + _basis(grid + np.pi, s.harmonics) @ coef
    centred = r[keep] - _basis(phi[keep], 1)[:, 1:] @ coef[1:3]
    medians = _cell_medians(centred, phi[keep], None if h is None else h[keep], s)
    if medians.size == 0:
        return None
    return SliceProfile(piece, round(float(h_c), 4), source, int(keep.sum()), float(D[180]), float(D[0]),
                        float(D.min()), float(D.max()), float((D.max() - D.min()) / D.mean() * 100.0),
                        float(max(0.0, radius - medians.min())), float(max(0.0, medians.max() - radius)))


def _cell_medians(centred: np.ndarray, phi: np.ndarray, h: np.ndarray | None, s: DeformationSettings) -> np.ndarray:
    """Median radius in cells of `bin_deg` around by `dent_cell_m` along (one ring when h is None) that hold
    at least three points: a dent between two slices still shows in the slice whose band holds it."""
    b = np.floor(np.mod(phi, 2 * np.pi) / np.radians(s.bin_deg)).astype(np.int64)
    if h is not None:
        b = b * 100000 + np.floor(h / s.dent_cell_m).astype(np.int64)
    keys, inv, counts = np.unique(b, return_inverse=True, return_counts=True)
    order = np.argsort(inv, kind="stable")
    groups = np.split(centred[order], np.cumsum(counts)[:-1])
    return np.array([np.median(g) for g, n in zip(groups, counts) if n >= 3])


def _basis(phi: np.ndarray, harmonics: int) -> np.ndarray:
    k = np.arange(1, harmonics + 1)
    a = np.outer(phi, k)
    return np.concatenate([np.ones((len(phi), 1)), np.cos(a), np.sin(a)], axis=1)[:, _order(harmonics)]


def _order(harmonics: int) -> np.ndarray:
    """Columns as 1, cos 1, sin 1, cos 2, sin 2, ... (the first harmonic's pair next to the constant)."""
    cols = [0]
    for k in range(1, harmonics + 1):
        cols += [k, harmonics + k]
    return np.array(cols)


def slice_positions(piece: WallPiece, s: DeformationSettings) -> np.ndarray:
    """h of the slices: every slice_m from the piece's start, inside the piece."""
    return np.arange(0.0, piece.length + 1e-9, s.slice_m)


def sparse_profiles(piece: WallPiece, points: np.ndarray, radius: float, s: DeformationSettings) -> list[SliceProfile]:
    """The piece's slices from scattered wall points (the sparse points triangulated without the cylinder)."""
    if len(points) == 0:
        return []
    h, phi, r = wall_samples(piece, points)
    near = np.abs(r - radius) < 0.25 * radius  # the tee's branch, a far wall seen through an opening
    out = []
    for h_c in slice_positions(piece, s):
        sel = near & (np.abs(h - h_c) <= s.sparse_band_m)
        p = profile(h_c, phi[sel], r[sel], radius, s, piece.name, "sparse", h[sel])
        if p is not None:
            out.append(p)
    return out


def deformation_csv(rows: list[SliceProfile]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for p in rows:
        d = asdict(p)
        w.writerow(["" if d[c] is None else (f"{d[c]:.6f}" if isinstance(d[c], float) else d[c]) for c in COLUMNS])
    return buf.getvalue()


def summary(rows: list[SliceProfile]) -> dict:
    """run.json `deformation`: per piece and source, the slices and the worst ovality and dent."""
    out: dict = {"slices": len(rows), "pieces": []}
    for name in dict.fromkeys(p.piece for p in rows):
        for source in ("sparse", "dense"):
            mine = [p for p in rows if p.piece == name and p.source == source]
            if not mine:
                continue
            worst = max(mine, key=lambda p: p.ovality_pct)
            dent = max(mine, key=lambda p: p.max_inward_m)
            out["pieces"].append({"piece": name, "source": source, "slices": len(mine),
                                  "max_ovality_pct": round(worst.ovality_pct, 3), "at_h_m": worst.h_m,
                                  "max_inward_m": round(dent.max_inward_m, 5), "inward_at_h_m": dent.h_m})
    return out
