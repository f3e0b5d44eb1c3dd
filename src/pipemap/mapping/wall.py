"""Straight pieces of fitted pipe wall and the regular (h, r*phi) grids the appearance map lives on.

Wall coordinates of a piece: h is metres along the axis from `start` (0 at start, `length` at
end); phi is the angle around the axis, 0 at 12 o'clock (the component of `up` perpendicular to
the axis) and increasing clockwise when looking along the axis from start to end. So, looking
down a horizontal pipe with z up, phi = pi/2 is 3 o'clock, the wall on the right.

A wall point is start + h u + b(h) + r (cos(phi) e_up + sin(phi) e_cw) with u the unit axis, e_up
the 12 o'clock direction, e_cw = u x e_up (3 o'clock) and b(h) the bend: the axis's offset across
u (a few millimetres where the run sags or kinks at a joint), linear between knots and constant
beyond the end knots (`pipemap.geometry.bend`); zero for a straight piece.

An elbow's wall (elbow_piece.py) has the same wall coordinates along its arc and the same methods
(wall_points, wall_coordinates, contains, exit, axis_distance, axis_polyline), so the grids, the
opening masks and the line-of-sight march here take either kind of piece.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from pipemap.errors import PipemapError
from pipemap.geometry.bend import AxisKnots

if TYPE_CHECKING:
    from pipemap.mapping.elbow_piece import ElbowPiece

# A grid point counts as inside another piece (a tee's branch opening) when it lies deeper than
# this inside that piece's solid cylinder, in units of the grid spacing: one spacing absorbs the
# sub-millimetre kinks where pieces of a sagging run meet.
INSIDE_MARGIN_SPACINGS = 1.0
MASK_ROWS = 256  # grid rows tested against the other pieces at a time


def three_vectors(obj, keys, where: str) -> dict[str, np.ndarray]:
    """obj's attributes `keys` as 3-vectors of floats; PipemapError naming the one that is not."""
    vals = {}
    for key in keys:
        try:
            v = np.asarray(getattr(obj, key), float).reshape(-1)
        except (TypeError, ValueError):
            v = np.zeros(0)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise PipemapError(f"{key} must be 3 finite numbers", where)
        vals[key] = v
    return vals


@dataclass(frozen=True)
class WallPiece:
    """A straight piece of fitted pipe wall, in the trajectory's world frame.

    name: e.g. "S1" or "T1-branch"; start, end: axis end points (h = 0 at start); radius: metres;
    up: a world direction whose component across the axis is 12 o'clock (phi = 0; phi grows
    clockwise looking from start to end); unroll: True for straight sections (they get an
    unrolled image), False for short tee stubs. bend_h (K,) increasing, bend_offsets (K, 3): the
    bend's knots (h) and the axis offsets there (world vectors across the axis); None: straight.
    """

    name: str
    start: np.ndarray
    end: np.ndarray
    radius: float
    up: np.ndarray
    unroll: bool = True
    bend_h: np.ndarray | None = None
    bend_offsets: np.ndarray | None = None

    kind: ClassVar[str] = "line"
    wall_in_sight_from_inside: ClassVar[bool] = True  # a straight tube's wall never hides itself
    along_stretch: ClassVar[float] = 1.0

    def __post_init__(self):
        where = f"wall piece {self.name!r}"
        vals = three_vectors(self, ("start", "end", "up"), where)
        r = float(self.radius)
        if not (math.isfinite(r) and r > 0):
            raise PipemapError(f"radius must be a positive number of metres, got {self.radius!r}", where)
        length = np.linalg.norm(vals["end"] - vals["start"])
        if not length > 0:
            raise PipemapError("start and end are the same point", where)
        u = (vals["end"] - vals["start"]) / length
        across = vals["up"] - (vals["up"] @ u) * u
        if np.linalg.norm(across) < 1e-6 * max(np.linalg.norm(vals["up"]), 1e-300):
            raise PipemapError("up is parallel to the axis: 12 o'clock is undefined", where)
        for key, v in vals.items():
            object.__setattr__(self, key, v)
        if (self.bend_h is None) != (self.bend_offsets is None):
            raise PipemapError("bend needs both h and offset", where)
        if self.bend_h is not None:
            try:
                bh = np.asarray(self.bend_h, float).reshape(-1)
                bo = np.asarray(self.bend_offsets, float).reshape(len(bh), 3)
            except (TypeError, ValueError):
                raise PipemapError("bend: h must be numbers and offset one [x, y, z] per h", where) from None
            if len(bh) < 2 or not (np.all(np.isfinite(bh)) and np.all(np.isfinite(bo))) or np.any(np.diff(bh) <= 0):
                raise PipemapError("bend: h must be at least two increasing finite numbers, offsets finite", where)
            object.__setattr__(self, "bend_h", bh)
            object.__setattr__(self, "bend_offsets", bo - np.outer(bo @ u, u))
        object.__setattr__(self, "radius", r)
        object.__setattr__(self, "unroll", bool(self.unroll))

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    @property
    def axis(self) -> np.ndarray:
        return (self.end - self.start) / self.length

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, e_up, e_cw): the unit axis, 12 o'clock and 3 o'clock (looking from start to end)."""
        u = self.axis
        e_up = self.up - (self.up @ u) * u
        e_up = e_up / np.linalg.norm(e_up)
        return u, e_up, np.cross(u, e_up)

    def wall_coordinates(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(h, phi in [0, 2 pi), distance from the axis) of world points (..., 3)."""
        u, e_up, e_cw = self.frame()
        q = np.asarray(points, float) - self.start
        h = q @ u
        x, y = q @ e_up, q @ e_cw
        return h, np.mod(np.arctan2(y, x), 2 * np.pi), np.hypot(x, y)

    def axis_offset(self, h) -> np.ndarray:
        """The bend b(h) (..., 3) at h (...,): zero for a straight piece."""
        h = np.asarray(h, float)
        if self.bend_h is None:
            return np.zeros(h.shape + (3,))
        return AxisKnots(self.bend_h).at(self.bend_offsets, h)

    def wall_points(self, h, phi) -> np.ndarray:
        """World points (len(h), len(phi), 3) of the wall at h (rows) and phi (columns)."""
        h, phi = np.asarray(h, float), np.asarray(phi, float)
        _, e_up, e_cw = self.frame()
        ring = np.cos(phi)[:, None] * e_up + np.sin(phi)[:, None] * e_cw
        axis_pts = self.start + h[:, None] * self.axis + self.axis_offset(h)
        return axis_pts[:, None, :] + self.radius * ring[None, :, :]

    def contains(self, points, margin: float = 0.0, h_margin: float = 0.0) -> np.ndarray:
        """Points (..., 3) inside the solid cylinder by more than margin (radially), between its ends widened by
        h_margin."""
        u = self.axis
        q = np.asarray(points, float) - self.start
        h = q @ u
        radial2 = np.einsum("...i,...i->...", q, q) - h * h
        r_in = max(self.radius - margin, 0.0)
        return (h >= -h_margin) & (h <= self.length + h_margin) & (radial2 < r_in * r_in)

    def exit(self, X: np.ndarray, D: np.ndarray, s: np.ndarray, tol_m: float) -> np.ndarray:
        """Line parameter where c + s D, now at X (inside or not), leaves the solid widened by tol_m; s where X
        is not inside it."""
        u = self.axis
        r = self.radius + tol_m
        q = X - self.start
        h = q @ u
        w = q - h[:, None] * u
        Du = D @ u
        v = D - Du[:, None] * u
        C = np.einsum("ij,ij->i", w, w) - r * r
        inside = (C <= 0) & (h >= -tol_m) & (h <= self.length + tol_m)
        A = np.einsum("ij,ij->i", v, v)
        B = np.einsum("ij,ij->i", w, v)
        with np.errstate(divide="ignore", invalid="ignore"):
            tau_cyl = np.where(A > 1e-18, (-B + np.sqrt(np.maximum(B * B - A * C, 0.0))) / A, np.inf)
            tau_end = np.where(Du > 0, (self.length + tol_m - h) / Du, np.where(Du < 0, (-tol_m - h) / Du, np.inf))
        tau = np.maximum(np.minimum(tau_cyl, tau_end), 0.0)
        return np.where(inside, s + tau, s)

    def holds_segment(self, X: np.ndarray, P: np.ndarray, tol: float) -> np.ndarray:
        """(n,) whether the segments X -> P lie inside the solid widened by tol: both ends in it (it is convex, the
        bend's millimetres aside)."""
        return self.contains(X, -tol, tol) & self.contains(P, -tol, tol)

    def axis_distance(self, point) -> float:
        """Distance from a point to the axis segment."""
        return point_segment_distance(np.asarray(point, float), self.start, self.end)

    def axis_polyline(self) -> np.ndarray:
        return np.stack([self.start, self.end])

    def to_dict(self) -> dict:
        d = {"name": self.name, "start": [float(v) for v in self.start], "end": [float(v) for v in self.end],
             "radius": self.radius, "up": [float(v) for v in self.up], "unroll": self.unroll}
        if self.bend_h is not None:
            d["bend"] = {"h": [round(float(v), 6) for v in self.bend_h],
                         "offset": [[round(float(v), 7) for v in row] for row in self.bend_offsets]}
        return d

    @classmethod
    def from_dict(cls, d: dict, where: str = "wall piece") -> "WallPiece":
        if not isinstance(d, dict):
            raise PipemapError("expected {name, start, end, radius, up, unroll}", where)
        missing = [k for k in ("name", "start", "end", "radius", "up") if k not in d]
        if missing:
            raise PipemapError(f"missing {', '.join(missing)}", where)
        try:
            radius = float(d["radius"])
        except (TypeError, ValueError):
            raise PipemapError(f"radius is not a number: {d['radius']!r}", where) from None
        bend = d.get("bend")
        if bend is not None and not (isinstance(bend, dict) and "h" in bend and "offset" in bend):
            raise PipemapError("bend must be {h: [...], offset: [[x, y, z], ...]}", where)
        try:
            return cls(str(d["name"]), d["start"], d["end"], radius, d["up"], bool(d.get("unroll", True)),
                       None if bend is None else bend["h"], None if bend is None else bend["offset"])
        except PipemapError as exc:
            raise PipemapError(exc.message, where) from None


@dataclass(frozen=True)
class WallGrid:
    """A piece's wall sampled at h[i] (rows) and phi[j] (columns): h from 0 to length inclusive,
    phi = j * 2 pi / W. Point (i, j) is the piece's wall point at (h[i], phi[j])."""

    piece: "WallPiece | ElbowPiece"
    h: np.ndarray  # (H,)
    phi: np.ndarray  # (W,)

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.h), len(self.phi)

    @property
    def spacing_h(self) -> float:
        return float(self.h[1] - self.h[0])

    @property
    def spacing_around(self) -> float:
        return float(self.piece.radius * 2 * np.pi / len(self.phi))

    def points(self, rows: slice | np.ndarray = slice(None)) -> np.ndarray:
        """World points (h rows, W, 3) of the grid rows `rows`."""
        return self.piece.wall_points(self.h[rows], self.phi)


def wall_grid(piece, spacing_m: float) -> WallGrid:
    """The regular (h, r phi) grid of `piece` at about `spacing_m` (exactly length / (H - 1) along and 2 pi r / W
    around; along an elbow's axis finer by its outside's stretch, so that its outer wall is sampled as finely)."""
    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise PipemapError(f"grid spacing must be positive, got {spacing_m!r}", key="appearance.spacing_m")
    n_h = max(2, int(round(piece.length * piece.along_stretch / spacing_m)) + 1)
    n_phi = max(8, int(round(2 * np.pi * piece.radius / spacing_m)))
    h = np.linspace(0.0, piece.length, n_h)
    phi = np.arange(n_phi) * (2 * np.pi / n_phi)
    return WallGrid(piece, h, phi)


def sample_wall(piece: WallPiece, spacing_m: float,
                others: list[WallPiece] | tuple = ()) -> tuple[np.ndarray, np.ndarray]:
    """The grid's 3D points (H, W, 3) and a mask (H, W), False where the point lies inside
    another piece's pipe (a tee's branch opening): the wall is not there."""
    grid = wall_grid(piece, spacing_m)
    return grid.points(), opening_mask(grid, others, INSIDE_MARGIN_SPACINGS * spacing_m)


def opening_mask(grid: WallGrid, others, margin_m: float) -> np.ndarray:
    """(H, W) True where the grid point is wall: not deeper than margin_m inside any other piece."""
    keep = np.ones(grid.shape, bool)
    near = [o for o in others if o is not grid.piece and _may_overlap(grid.piece, o)]
    if not near:
        return keep
    for start in range(0, grid.shape[0], MASK_ROWS):  # a long piece's points at once would take gigabytes
        rows = slice(start, start + MASK_ROWS)
        P = grid.points(rows)
        for other in near:
            keep[rows] &= ~inside_piece(P, other, margin_m)
    return keep


def inside_piece(points: np.ndarray, piece, margin_m: float = 0.0, h_margin_m: float = 0.0) -> np.ndarray:
    """Points (..., 3) inside the solid of `piece` (a cylinder or an elbow's bent tube) by more than margin_m
    (radially), between its ends widened by h_margin_m."""
    return piece.contains(points, margin_m, h_margin_m)


def _may_overlap(a, b) -> bool:
    """Whether the capsules around the two axes (radius r; an elbow's axis as its polyline) can touch."""
    pa, pb = a.axis_polyline(), b.axis_polyline()
    return min(segment_distance(pa[i], pa[i + 1], pb[k], pb[k + 1])
               for i in range(len(pa) - 1) for k in range(len(pb) - 1)) <= a.radius + b.radius


def segment_distance(p0, p1, q0, q1) -> float:
    """Shortest distance between segments p0-p1 and q0-q1."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, b = d1 @ r, d1 @ d2
    den = a * e - b * b
    s = np.clip((b * f - c * e) / den, 0.0, 1.0) if den > 1e-12 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0 or t > 1:
        t = np.clip(t, 0.0, 1.0)
        s = np.clip((b * t - c) / a, 0.0, 1.0)
    return float(np.linalg.norm(p0 + s * d1 - (q0 + t * d2)))


def point_segment_distance(x, p0, p1) -> float:
    d = p1 - p0
    s = np.clip((x - p0) @ d / (d @ d), 0.0, 1.0)
    return float(np.linalg.norm(x - (p0 + s * d)))


def in_line_of_sight(centre: np.ndarray, points: np.ndarray, pieces, tol_m: float, hops: int = 4) -> np.ndarray:
    """(N,) whether the straight line from `centre` to each point (N, 3) stays inside the pipes
    (the union of the pieces' solids, cylinders and elbows' bent tubes, widened by tol_m).

    Marches along each line: where the rest of the line lies in one piece, it is in sight; else
    from the current place, every piece that contains it gives the
    parameter where the line leaves that piece (its wall or its end planes); the march jumps
    to the farthest such exit. The point is in sight when that reaches it within `hops` jumps
    (one per piece boundary crossed: a tee opening is one)."""
    c = np.asarray(centre, float)
    D = np.asarray(points, float) - c  # the line is c + s D, s in [0, 1]
    n = len(D)
    length = np.linalg.norm(D, axis=1)
    s = np.zeros(n)
    done = np.zeros(n, bool)
    todo = np.arange(n)
    P = np.asarray(points, float)
    for _ in range(hops):
        if not len(todo):
            break
        X = c + s[todo, None] * D[todo]
        held = np.zeros(len(todo), bool)
        for piece in pieces:  # the rest of the line lies in one piece: in sight, no march needed
            held |= piece.holds_segment(X, P[todo], tol_m)
        done[todo[held]] = True
        todo, X = todo[~held], X[~held]
        if not len(todo):
            break
        Dt = D[todo]
        best = s[todo].copy()
        for piece in pieces:
            best = np.maximum(best, piece.exit(X, Dt, s[todo], tol_m))
        reached = best * length[todo] >= length[todo] - tol_m
        done[todo[reached]] = True
        moved = best > s[todo] + 1e-9
        s[todo] = best
        todo = todo[~reached & moved]
    return done


__all__ = ["WallPiece", "WallGrid", "wall_grid", "sample_wall", "opening_mask", "inside_piece", "in_line_of_sight",
           "segment_distance", "point_segment_distance", "INSIDE_MARGIN_SPACINGS"]
