"""Deformed pipe pieces: an oval cross-section and local dents, and exact ray casting into them.

A straight piece may carry a `WallShape`: its wall lies at radius R + d(h, clock) from the piece's
axis, with d the outward deviation. Clock angles follow the results contract: 0 at the piece's 12
o'clock (`Pipe.frame`'s e1), increasing clockwise looking from start to end.

- Ovality: an ellipse with the *same mean diameter* as the round pipe, semi-axes a = R (1 + e) and
  b = R (1 - e), so that ovality = (Dmax - Dmin) / Dmean = 2 e (the definition in docs/formats.md).
  Its major axis lies at `major_clock_deg`. The ellipse blends in over `taper_m` at each end of the
  piece (a raised cosine of h), so the wall has no step where it meets a round neighbour.
- A dent pushes the wall inwards by `depth_m` at its centre, falling off as cos^2 along (full extent
  `length_m`) and around (full extent `width_deg`).

Ray casting: the round pipe's hit is refined on the true surface. The visible point is the first
root of f(t) = rho(t) - R - d(h(t), clock(t)) along the ray, where rho is the distance from the
axis: f < 0 where the ray leaves the cylinder of radius R - (deepest inward deviation), f > 0 where it
leaves the one of radius R + (largest outward deviation). The bracket is searched in `MARCH_STEPS`
steps for its first sign change, then solved there by regula falsi (Illinois) to float64 precision. A
wall feature narrower than a step along a grazing ray could be jumped over; the preset's features span
many steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipemap.errors import PipemapError

MARCH_STEPS = 12
ILLINOIS_STEPS = 12


@dataclass(frozen=True)
class Dent:
    """A local inward dent: centre at `h_m` along the piece and `clock_deg`, depth, full extents."""

    h_m: float
    clock_deg: float
    depth_m: float
    length_m: float = 0.3
    width_deg: float = 60.0

    def to_dict(self) -> dict:
        return {"h_m": self.h_m, "clock_deg": self.clock_deg, "depth_m": self.depth_m, "length_m": self.length_m,
                "width_deg": self.width_deg}


@dataclass(frozen=True)
class WallShape:
    """A piece's cross-section: ovality (percent, (Dmax - Dmin) / Dmean) with its major axis's clock
    angle, and dents."""

    ovality_pct: float = 0.0
    major_clock_deg: float = 0.0
    dents: tuple[Dent, ...] = field(default_factory=tuple)
    taper_m: float = 0.05

    def check(self, length: float, radius: float, where: str) -> None:
        if not 0 <= self.ovality_pct < 50:
            raise PipemapError(f"ovality must be in [0, 50) percent, got {self.ovality_pct}", where)
        if not 0 <= 2 * self.taper_m <= length:
            raise PipemapError(f"the ovality's taper {self.taper_m} m does not fit the piece of {length:.3f} m", where)
        for d in self.dents:
            if not (0 < d.depth_m < radius and d.length_m > 0 and 0 < d.width_deg <= 360):
                raise PipemapError("a dent needs a depth in (0, R), a positive length and a width in (0, 360] deg",
                                   where)
            if d.h_m - d.length_m / 2 < 0 or d.h_m + d.length_m / 2 > length:
                raise PipemapError(f"the dent at h = {d.h_m} m reaches beyond the piece", where)

    def bounds(self, radius: float) -> tuple[float, float]:
        """(deepest inward, largest outward) deviation, metres (both >= 0)."""
        e = self.ovality_pct / 200.0
        return radius * e + sum(d.depth_m for d in self.dents), radius * e

    def deviation(self, h: np.ndarray, clock: np.ndarray, radius: float, length: float) -> np.ndarray:
        """Outward deviation d (metres) of the wall from radius R at h (metres from the piece's start) and
        clock angle (radians, clockwise from 12 o'clock); zero outside [0, length]."""
        h = np.asarray(h, float)
        clock = np.asarray(clock, float)
        out = np.zeros(np.broadcast(h, clock).shape)
        inside = (h >= 0) & (h <= length)
        if self.ovality_pct:
            e = self.ovality_pct / 200.0
            a, b = radius * (1 + e), radius * (1 - e)
            psi = clock - np.radians(self.major_clock_deg)
            ellipse = a * b / np.sqrt((b * np.cos(psi)) ** 2 + (a * np.sin(psi)) ** 2) - radius
            out += np.where(inside, ellipse * self.taper(h, length), 0.0)
        for d in self.dents:
            along = _bump(h - d.h_m, d.length_m)
            around = _bump(np.mod(clock - np.radians(d.clock_deg) + np.pi, 2 * np.pi) - np.pi, np.radians(d.width_deg))
            out -= d.depth_m * along * around
        return out

    def taper(self, h: np.ndarray, length: float) -> np.ndarray:
        """1 in the piece's middle, falling to 0 at its ends as a raised cosine over `taper_m`."""
        if self.taper_m <= 0:
            return np.ones_like(h)
        x = np.clip(np.minimum(h, length - h) / self.taper_m, 0.0, 1.0)
        return 0.5 - 0.5 * np.cos(np.pi * x)

    def to_dict(self) -> dict:
        return {"ovality_pct": self.ovality_pct, "major_clock_deg": self.major_clock_deg, "taper_m": self.taper_m,
                "dents": [d.to_dict() for d in self.dents]}


def deformation_truth(scene) -> dict | None:
    """ground_truth/deformation.yaml (`pipemap-deformation-truth/1`): every shaped piece with its axis and 12
    o'clock; None when no piece is shaped."""
    pieces = [{"id": p.id, "start": [float(v) for v in p.start], "end": [float(v) for v in p.end],
               "up": [float(v) for v in p.frame[0]], **p.shape.to_dict()} for p in scene.pipes if p.shape is not None]
    if not pieces:
        return None
    return {"format": "pipemap-deformation-truth/1", "radius_m": float(scene.radius),
            "ovality": "(Dmax - Dmin) / Dmean * 100, ellipse of the round pipe's mean diameter", "pieces": pieces}


def _bump(x: np.ndarray, full: float) -> np.ndarray:
    """cos^2 bump of full width `full`: 1 at 0, 0 at and beyond +-full / 2."""
    with np.errstate(invalid="ignore"):
        return np.where(np.abs(x) < full / 2, np.cos(np.pi * x / full) ** 2, 0.0)


@dataclass(frozen=True)
class ShapedLine:
    """Collinear straight pieces (one straight run) of which some carry a shape: the line's origin and
    unit axis, and per piece its index, offset along the line and extent."""

    origin: np.ndarray
    axis: np.ndarray
    e1: np.ndarray  # 12 o'clock of the shaped pieces (they share one)
    pieces: tuple  # (index, h offset of the piece's start, length, shape or None)
    h_lo: float  # where any shape starts / ends along the line
    h_hi: float
    inward: float  # the line's deepest inward and largest outward deviation
    outward: float

    def deviation(self, h_line: np.ndarray, clock: np.ndarray, radius: float) -> np.ndarray:
        h_line, clock = np.broadcast_arrays(np.asarray(h_line, float), np.asarray(clock, float))
        out = np.zeros(h_line.shape)
        for _, off, length, shape in self.pieces:
            if shape is not None:
                sel = (h_line >= off) & (h_line <= off + length)
                out[sel] = shape.deviation(h_line[sel] - off, clock[sel], radius, length)
        return out

    def piece_at(self, h_line: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(piece index, h along that piece) of line positions: the piece whose extent holds them."""
        offs = np.array([p[1] for p in self.pieces])
        k = np.clip(np.searchsorted(offs, h_line, side="right") - 1, 0, len(offs) - 1)
        idx = np.array([p[0] for p in self.pieces])
        return idx[k], h_line - offs[k]


def shaped_lines(scene) -> list[ShapedLine]:
    """The straight runs of `scene` holding shaped pieces: a shaped piece's collinear neighbours form its
    line (a shaped piece must be collinear with the pieces it meets, so its wall meets theirs)."""
    lines: list[ShapedLine] = []
    seen: set[int] = set()
    for k, p in enumerate(scene.pipes):
        if p.shape is None or k in seen:
            continue
        u, o = p.axis, p.start
        members = []
        for j, q in enumerate(scene.pipes):
            on = abs(abs(q.axis @ u) - 1) < 1e-12 and np.linalg.norm(np.cross(q.start - o, u)) < 1e-9
            if on and q.axis @ u > 0:
                members.append((j, float((q.start - o) @ u), q.length, q.shape))
        members.sort(key=lambda m: m[1])
        seen.update(m[0] for m in members)
        shaped = [m for m in members if m[3] is not None]
        for _, _, length, shape in shaped:
            shape.check(length, scene.radius, f"pipe piece {scene.pipes[k].id}")
        bounds = np.array([m[3].bounds(scene.radius) for m in shaped])
        lines.append(ShapedLine(o.copy(), u.copy(), p.frame[0], tuple(members), min(m[1] for m in shaped),
                                max(m[1] + m[2] for m in shaped), float(bounds[:, 0].sum()),
                                float(bounds[:, 1].max())))
    return lines


def refine_hits(lines: list[ShapedLine], radius: float, R_wc: np.ndarray, origin: np.ndarray, B: np.ndarray,
                hits) -> None:
    """Move the round pipe's hits (raycast.Hits, changed in place) onto the shaped walls of `lines`, for the
    rays B (3, N, camera frame) from `origin`."""
    for line in lines:
        members = np.array([m[0] for m in line.pieces])
        idx = np.flatnonzero(np.isin(hits.pipe, members) & ~hits.cap)
        if idx.size == 0:
            continue
        D = np.asarray(R_wc, float) @ np.asarray(B[:, idx], float)
        D /= np.linalg.norm(D, axis=0)
        q0 = np.asarray(origin, float) - line.origin
        h0 = float(q0 @ line.axis)
        w0 = q0 - h0 * line.axis
        du = line.axis @ D
        wd = D - np.outer(line.axis, du)
        A = np.einsum("ij,ij->j", wd, wd)
        Bq = w0 @ wd
        C = float(w0 @ w0)
        t_lo = _exit(A, Bq, C, radius - line.inward - 1e-9)
        t_hi = _exit(A, Bq, C, radius + line.outward + 1e-9)
        h_a, h_b = h0 + t_lo * du, h0 + t_hi * du
        near = (np.maximum(h_a, h_b) >= line.h_lo) & (np.minimum(h_a, h_b) <= line.h_hi)
        near &= np.isfinite(t_lo) & np.isfinite(t_hi) & (hits.t[idx] >= t_lo - 1e-6)
        if not near.any():
            continue
        sel = idx[near]
        t = _first_root(line, radius, q0, D[:, near], t_lo[near], t_hi[near])
        h_line = h0 + t * du[near]
        piece, h = line.piece_at(h_line)
        hits.t[sel] = t.astype(hits.t.dtype)
        hits.pipe[sel] = piece
        hits.h[sel] = h.astype(hits.h.dtype)


def _exit(A: np.ndarray, Bq: np.ndarray, C: float, r: float) -> np.ndarray:
    """The far root t of |w0 + t wd| = r (the ray leaving the cylinder of radius r); NaN when it misses."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return (-Bq + np.sqrt(Bq * Bq - A * (C - r * r))) / A


def _first_root(line: ShapedLine, radius: float, q0: np.ndarray, D: np.ndarray, t_lo: np.ndarray,
                t_hi: np.ndarray) -> np.ndarray:
    """The first root of f in [t_lo, t_hi]: a march for the first sign change, then the Illinois variant of
    regula falsi inside it (superlinear, and it keeps the bracket)."""
    e_cw = np.cross(line.axis, line.e1)
    x0, y0, h0 = float(q0 @ line.e1), float(q0 @ e_cw), float(q0 @ line.axis)
    dx, dy, dh = line.e1 @ D, e_cw @ D, line.axis @ D

    def f(t, rows=slice(None)):
        ex = (slice(None),) + (None,) * (t.ndim - 1)
        x, y = x0 + t * dx[rows][ex], y0 + t * dy[rows][ex]
        return np.hypot(x, y) - radius - line.deviation(h0 + t * dh[rows][ex], np.arctan2(y, x), radius)

    steps = t_lo[:, None] + (t_hi - t_lo)[:, None] * np.linspace(0.0, 1.0, MARCH_STEPS + 1)[None]
    values = f(steps)
    values[:, 0] = np.minimum(values[:, 0], -1e-300)
    values[:, -1] = np.maximum(values[:, -1], 0.0)
    j = np.argmax(values[:, 1:] >= 0, axis=1)  # the first step that ends at or beyond the wall
    rows = np.arange(len(t_lo))
    a, b = steps[rows, j], steps[rows, j + 1]
    fa, fb = values[rows, j], values[rows, j + 1]
    side = np.zeros(len(a), np.int8)
    c = b
    for _ in range(ILLINOIS_STEPS):
        c = b - fb * (b - a) / np.where(fb - fa != 0, fb - fa, 1.0)
        c = np.clip(c, np.minimum(a, b), np.maximum(a, b))
        fc = f(c)
        beyond = fc >= 0
        fa = np.where(beyond & (side == 1), fa / 2, fa)
        fb = np.where(~beyond & (side == -1), fb / 2, fb)
        b, fb = np.where(beyond, c, b), np.where(beyond, fc, fb)
        a, fa = np.where(beyond, a, c), np.where(beyond, fa, fc)
        side = np.where(beyond, 1, -1).astype(np.int8)
    return c
