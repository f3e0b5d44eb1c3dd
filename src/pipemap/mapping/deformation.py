"""Deformation of the straight pieces: ovality, X/Y diameters and the largest inward and outward deviation
(a dent) every `slice_m` along each piece, as laser profilers report them (ASTM F3080: every 10 cm).

Per slice, the wall points near it are taken in the piece's wall coordinates (h, phi clockwise from 12
o'clock, distance from the bent axis) and r(phi) is fitted as a Fourier series of `harmonics` terms by
least squares, dropping points more than `outlier_mads` MADs off. The diameter in direction phi is
D(phi) = r(phi) + r(phi + pi) (odd terms, a centre offset among them, cancel), so:

- diameter_y (vertical: 12 to 6 o'clock) = D(0), diameter_x (horizontal: 3 to 9 o'clock) = D(pi/2);
- diameter_min / diameter_max = the least and greatest D(phi); ovality % = (Dmax - Dmin) / Dmean * 100 with
  Dmean the mean of D(phi) over all directions (for an ellipse, twice ASTM F1216's (Dmean - Dmin) / Dmean);
- max_inward / max_outward: the largest deviation below / above the a-priori radius over the slice's band, after
  the centre offset is taken out: from the sparse points, the wall field (wall_field.py: a robust local quadratic
  fit of the deviation over h and phi with an adaptive neighbourhood), so that a dent between two slice
  positions is not missed and its deepest point is not averaged away; the centre follows the slices' first
  harmonic smoothed robustly along the piece (a dent's own first harmonic would otherwise take out part of
  it). From the dense ring of cells: the medians of `bin_deg` cells around.
"""

from __future__ import annotations

import csv
import io
from dataclasses import asdict, dataclass

import numpy as np

from pipemap.config import DeformationSettings
from pipemap.mapping.wall import WallPiece
from pipemap.mapping.wall_field import wall_field

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


def ring_fit(phi: np.ndarray, r: np.ndarray, s: DeformationSettings) -> tuple[np.ndarray, np.ndarray] | None:
    """The Fourier coefficients of r(phi) and the points kept (None: too few points, or they leave the circle
    open)."""
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
    return coef, keep


def ring_profile(h_c: float, coef: np.ndarray, points: int, piece: str, source: str, inward: float,
                 outward: float, harmonics: int) -> SliceProfile:
    """A slice's diameters and ovality from its Fourier coefficients, with its largest deviations."""
    grid = np.linspace(0.0, np.pi, 360, endpoint=False)
    D = _basis(grid, harmonics) @ coef + _basis(grid + np.pi, harmonics) @ coef
    return SliceProfile(piece, round(float(h_c), 4), source, int(points), float(D[180]), float(D[0]),
                        float(D.min()), float(D.max()), float((D.max() - D.min()) / D.mean() * 100.0),
                        _at_least_zero(inward), _at_least_zero(outward))


def _at_least_zero(x: float) -> float:
    return float(max(0.0, x)) if np.isfinite(x) else float("nan")


def profile(h_c: float, phi: np.ndarray, r: np.ndarray, radius: float, s: DeformationSettings, piece: str,
            source: str) -> SliceProfile | None:
    """The slice at h_c from a ring of radii r(phi) (the dense cells): the deviations from the medians of
    `bin_deg` cells around after the fitted centre offset is taken out (None: too few, or the circle open)."""
    fit = ring_fit(phi, r, s)
    if fit is None:
        return None
    coef, keep = fit
    centred = r[keep] - _basis(phi[keep], 1)[:, 1:] @ coef[1:3]
    b = np.floor(np.mod(phi[keep], 2 * np.pi) / np.radians(s.bin_deg)).astype(np.int64)
    medians = np.array([np.median(centred[b == k]) for k in np.unique(b)])
    return ring_profile(h_c, coef, int(keep.sum()), piece, source, radius - medians.min(), medians.max() - radius,
                        s.harmonics)


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
    """The piece's slices from scattered wall points (the sparse points triangulated without the cylinder):
    ovality and diameters from each slice's ring fit; the largest deviations from the wall field (a local
    smooth fit of the deviation over h and phi, wall_field.py) over the slice's band, about a centre that
    follows the ring fits' first harmonic smoothly along the piece."""
    if len(points) == 0:
        return []
    h, phi, r = wall_samples(piece, points)
    near = np.abs(r - radius) < 0.25 * radius  # the tee's branch, a far wall seen through an opening
    h, phi, r = h[near], phi[near], r[near]
    rings = []
    for h_c in slice_positions(piece, s):
        sel = np.abs(h - h_c) <= s.sparse_band_m
        fit = ring_fit(phi[sel], r[sel], s)
        if fit is not None:
            rings.append((float(h_c), fit[0], int(fit[1].sum())))
    if not rings:
        return []
    hs = np.array([g[0] for g in rings])
    centre = smooth_centre(hs, np.array([g[1][1:3] for g in rings]), s.centre_window_m)
    offset = np.column_stack([np.interp(h, hs, centre[:, 0]), np.interp(h, hs, centre[:, 1])])
    d = r - radius - np.einsum("ni,ni->n", _basis(phi, 1)[:, 1:], offset)
    grid = np.arange(hs[0] - s.sparse_band_m, hs[-1] + s.sparse_band_m + 1e-9, s.dent_grid_m)
    field = wall_field(h, phi, d, radius, grid, grid_m=s.dent_grid_m, neighbours=tuple(s.dent_neighbours),
                       gamma=s.dent_ici_gamma, outlier_mads=s.dent_outlier_mads, reach_m=s.dent_reach_m)
    out = []
    for h_c, coef, n in rings:
        inward = outward = np.nan
        if field is not None:
            v = field.value[(np.abs(field.h - h_c) <= s.sparse_band_m + 1e-9) & np.isfinite(field.value)]
            if v.size:
                inward, outward = -float(v.min()), float(v.max())
        out.append(ring_profile(h_c, coef, n, piece.name, "sparse", inward, outward, s.harmonics))
    return out


def smooth_centre(hs: np.ndarray, offsets: np.ndarray, window_m: float) -> np.ndarray:
    """The slices' centre offsets (first harmonic, (n, 2)) smoothed along the piece by a robust local line
    (tricube over +-window_m, bisquare robustness weights): the axis bends slowly, while a dent's own first
    harmonic shifts a few neighbouring slices, which the robustness weights set aside."""
    if len(hs) < 4:
        return np.repeat(np.median(offsets, axis=0, keepdims=True), len(hs), axis=0)
    gap = np.abs(hs[:, None] - hs[None, :]) / window_m
    near = np.where(gap < 1, (1 - gap ** 3) ** 3, 0.0)
    robust = np.ones(len(hs))
    X = np.column_stack([np.ones_like(hs), hs])
    for _ in range(4):
        fitted = np.empty_like(offsets)
        for i in range(len(hs)):
            w = near[i] * robust
            if np.count_nonzero(w) < 3:
                w = near[i]
            A = X.T @ (w[:, None] * X) + np.eye(2) * 1e-12
            fitted[i] = X[i] @ np.linalg.solve(A, X.T @ (w[:, None] * offsets))
        res = np.linalg.norm(offsets - fitted, axis=1)
        u = res / (6.0 * np.median(res) + 1e-9)
        robust = np.where(u < 1, (1 - u ** 2) ** 2, 0.0)
    return fitted


def deformation_csv(rows: list[SliceProfile]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for p in rows:
        d = asdict(p)
        w.writerow([_cell(d[c]) for c in COLUMNS])
    return buf.getvalue()


def _cell(v) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    return f"{v:.6f}" if isinstance(v, float) else str(v)


def summary(rows: list[SliceProfile]) -> dict:
    """run.json `deformation`: per piece and source, the slices and the worst ovality and dent."""
    out: dict = {"slices": len(rows), "pieces": []}
    for name in dict.fromkeys(p.piece for p in rows):
        for source in ("sparse", "dense"):
            mine = [p for p in rows if p.piece == name and p.source == source]
            if not mine:
                continue
            worst = max(mine, key=lambda p: p.ovality_pct)
            dent = max(mine, key=lambda p: np.nan_to_num(p.max_inward_m, nan=-1.0))
            out["pieces"].append({"piece": name, "source": source, "slices": len(mine),
                                  "max_ovality_pct": round(worst.ovality_pct, 3), "at_h_m": worst.h_m,
                                  "max_inward_m": round(dent.max_inward_m, 5), "inward_at_h_m": dent.h_m})
    return out
