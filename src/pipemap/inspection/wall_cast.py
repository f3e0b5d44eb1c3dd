"""Where a camera ray meets the fitted pipe wall: the result's straight wall pieces (cylinders) and the route's
elbow arcs (torus pieces).

The pipe's inside is the union of the pieces' solid tubes; a ray from a camera inside it meets the wall where it
first leaves a tube at a point that lies inside no other tube (a tee's opening is no wall). Each cylinder's
exit root (the larger root of the ray-cylinder quadratic) and each torus's exit roots (the second and fourth of
the sorted quartic roots) are the candidates. The route's first and last pieces reach on past its ends: the
wall behind the first camera and ahead of the last one is still pipe.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.geometry.torus import TorusPiece
from pipemap.inspection.route import Route

OPEN_END_RADII = 10.0  # how far the first and last pieces reach past the route's ends
INSIDE_MARGIN_M = 1e-4  # a hit counts as inside another tube only this much deeper than its wall


@dataclass(frozen=True)
class Tube:
    """A straight solid tube from `start` to `end` of `radius`."""

    start: np.ndarray
    end: np.ndarray
    radius: float

    @property
    def axis(self) -> tuple[np.ndarray, float]:
        d = self.end - self.start
        n = float(np.linalg.norm(d))
        return d / n, n


# An elbow's solid torus piece: centre, unit normal (the arc turns anticlockwise about it), e1 (from the centre
# to the arc's start), bend radius, angle turned and tube radius.
Bend = TorusPiece


def wall_shapes(pieces: list[dict], route: Route) -> tuple[list[Tube], list[Bend]]:
    """The tubes of run.json `wall_pieces` (the first and last opened past the route's ends) and the bends
    of the route's arcs (the elbows' own wall pieces in `pieces` are those arcs)."""
    pieces = [p for p in pieces if p.get("kind", "line") == "line"]
    tubes = []
    for k, p in enumerate(pieces):
        a, b = np.asarray(p["start"], float), np.asarray(p["end"], float)
        u = (b - a) / np.linalg.norm(b - a)
        reach = OPEN_END_RADII * float(p["radius"])
        tubes.append(Tube(a - (reach * u if k == 0 else 0.0), b + (reach * u if k == len(pieces) - 1 else 0.0),
                          float(p["radius"])))
    bends = [Bend(s.centre, s.normal, (s.start - s.centre) / s.bend_radius, s.bend_radius, s.angle, route.radius)
             for s in route.segments if s.kind == "arc"]
    return tubes, bends


def _tube_exit(tube: Tube, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Distance (n,) to where each ray leaves the tube's lateral wall within its ends (inf: nowhere ahead)."""
    u, length = tube.axis
    o = origin - tube.start
    w0 = o - (o @ u) * u
    v = dirs - (dirs @ u)[:, None] * u
    A = np.einsum("ij,ij->i", v, v)
    B = v @ w0
    C = w0 @ w0 - tube.radius**2
    disc = B * B - A * C
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-B + np.sqrt(np.maximum(disc, 0.0))) / A
    h = o @ u + t * (dirs @ u)
    ok = (disc >= 0) & (A > 1e-15) & (t > 0) & (h >= 0) & (h <= length)
    return np.where(ok, t, np.inf)


def _inside(points: np.ndarray, tubes: list[Tube], bends: list[Bend]) -> np.ndarray:
    """(n, shapes) whether each point lies deeper than INSIDE_MARGIN_M inside each tube, then each bend."""
    cols = []
    for tube in tubes:
        u, length = tube.axis
        q = points - tube.start
        h = q @ u
        rho = np.linalg.norm(q - h[:, None] * u, axis=1)
        cols.append((h >= 0) & (h <= length) & (rho < tube.radius - INSIDE_MARGIN_M))
    cols += [bend.contains(points, INSIDE_MARGIN_M) for bend in bends]
    return np.stack(cols, axis=1) if cols else np.zeros((len(points), 0), bool)


def cast_to_wall(origin, dirs, tubes: list[Tube], bends: list[Bend]) -> tuple[np.ndarray, np.ndarray]:
    """World points (n, 3) where rays from `origin` along unit `dirs` (n, 3) meet the wall, and whether they do."""
    origin = np.asarray(origin, float)
    dirs = np.atleast_2d(np.asarray(dirs, float))
    shapes = [(_tube_exit, s) for s in tubes] + [(Bend.wall_exit, s) for s in bends]
    if not shapes:
        return np.full((len(dirs), 3), np.nan), np.zeros(len(dirs), bool)
    t = np.stack([fn(shape, origin, dirs) for fn, shape in shapes], axis=1)  # (n, shapes)
    order = np.argsort(t, axis=1)
    best = np.full(len(dirs), np.inf)
    todo = np.ones(len(dirs), bool)
    rows = np.arange(len(dirs))
    for k in range(len(shapes)):  # the nearest candidate that lies in no other tube
        j = order[:, k]
        tk = t[rows, j]
        p = origin + np.where(np.isfinite(tk), tk, 0.0)[:, None] * dirs
        inside = _inside(p, tubes, bends)
        inside[rows, j] = False
        take = todo & np.isfinite(tk) & ~inside.any(axis=1)
        best[take] = tk[take]
        todo &= ~take & np.isfinite(tk)
        if not todo.any():
            break
    ok = np.isfinite(best)
    return origin + np.where(ok, best, np.nan)[:, None] * dirs, ok


__all__ = ["Tube", "Bend", "wall_shapes", "cast_to_wall"]
