"""Where a camera ray meets the fitted pipe wall: the result's straight wall pieces (cylinders) and the route's
elbow arcs (torus pieces).

The pipe's inside is the union of the pieces' solid tubes; a ray from a camera inside it meets the wall where it
first leaves a tube at a point that lies inside no other tube (a tee's opening is no wall). Each cylinder's
exit root (the larger root of the ray-cylinder quadratic) and each torus's exit roots (the second and fourth of
the sorted quartic roots) are the candidates. The route's first and last pieces reach on past its ends: the
wall behind the first camera and ahead of the last one is still pipe; so is the through pipe past a tee where
the route turns (its wall piece ends one radius past the tee's centre, at the far wall: the stub beyond is seen
but not mapped). Those reaches are a guess where nothing was mapped, so they hide no mapped wall (on a loop the
first piece's reach crosses the tee behind the start and the pieces of the route's other end).

A camera sees the pipe within a few radii of itself (route.SIGHT_RADII): `in_sight` keeps the shapes whose
route chainage comes that near the camera's, so that where a loop passes a place twice, the wall met is the
camera's own pass's fit of it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipemap.geometry.torus import TorusPiece
from pipemap.inspection.route import SIGHT_RADII, Route

OPEN_END_RADII = 10.0  # how far the first and last pieces, and through pipes into a tee's stub, reach on
THROUGH_RADII = 0.5  # a piece that runs on past its route segment's end by more than this runs through a tee
INSIDE_MARGIN_M = 1e-4  # a hit counts as inside another tube only this much deeper than its wall


@dataclass(frozen=True)
class Tube:
    """A straight solid tube from `start` to `end` of `radius`, named as its route segment; its wall (not its
    solid) reaches on `reach_start` before the start and `reach_end` past the end."""

    start: np.ndarray
    end: np.ndarray
    radius: float
    name: str = ""
    reach_start: float = 0.0
    reach_end: float = 0.0

    @property
    def axis(self) -> tuple[np.ndarray, float]:
        d = self.end - self.start
        n = float(np.linalg.norm(d))
        return d / n, n


@dataclass(frozen=True)
class Bend(TorusPiece):
    """An elbow's solid torus piece (`geometry.torus.TorusPiece`) with its route segment's name."""

    name: str = ""


def wall_shapes(pieces: list[dict], route: Route) -> tuple[list[Tube], list[Bend]]:
    """The tubes of run.json `wall_pieces` (the first and last reaching on past the route's ends, through pipes
    into the stubs of tees) and the bends of the route's arcs."""
    segs = {s.name: s for s in route.segments if s.kind == "line"}
    pieces = [p for p in pieces if p.get("kind", "line") == "line"]  # an elbow's own piece is its route arc
    tubes = []
    for k, p in enumerate(pieces):
        start, end, r = np.asarray(p["start"], float), np.asarray(p["end"], float), float(p["radius"])
        reach = OPEN_END_RADII * r
        before, past = _runs_on(segs.get(str(p.get("name", ""))), start, end, THROUGH_RADII * r)
        tubes.append(Tube(start, end, r, str(p.get("name", "")), reach if k == 0 or before else 0.0,
                          reach if k == len(pieces) - 1 or past else 0.0))
    bends = [Bend(s.centre, s.normal, (s.start - s.centre) / s.bend_radius, s.bend_radius, s.angle, route.radius,
                  s.name) for s in route.segments if s.kind == "arc"]
    return tubes, bends


def _runs_on(seg, start: np.ndarray, end: np.ndarray, margin: float) -> tuple[bool, bool]:
    """Whether a piece runs on more than `margin` before its route segment's start and past its end."""
    if seg is None:
        return False, False
    u = (end - start) / np.linalg.norm(end - start)
    return bool((seg.start - start) @ u > margin), bool((end - seg.end) @ u > margin)


def in_sight(tubes: list[Tube], bends: list[Bend], route: Route, chainage: float) -> tuple[list[Tube], list[Bend]]:
    """The shapes whose route segments come within SIGHT_RADII radii (along the route) of `chainage`; shapes on
    no route segment are kept."""
    reach = SIGHT_RADII * route.radius
    spans: dict[str, list[tuple[float, float]]] = {}
    for seg in route.segments:
        spans.setdefault(seg.name, []).append((seg.chainage_start, seg.chainage_end))

    def near(name: str) -> bool:
        return name not in spans or any(a - reach <= chainage <= b + reach for a, b in spans[name])

    return [t for t in tubes if near(t.name)], [b for b in bends if near(b.name)]


def thicker(tubes: list[Tube], bends: list[Bend], by: float) -> tuple[list[Tube], list[Bend]]:
    """The same shapes with their radius `by` metres larger."""
    return [replace(t, radius=t.radius + by) for t in tubes], [replace(b, radius=b.radius + by) for b in bends]


def _tube_exit(tube: Tube, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Distance (n,) to where each ray leaves the tube's lateral wall within its ends and reaches (inf: nowhere
    ahead)."""
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
    ok = (disc >= 0) & (A > 1e-15) & (t > 0) & (h >= -tube.reach_start) & (h <= length + tube.reach_end)
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
    for bend in bends:
        q = points - bend.centre
        z = q @ bend.normal
        flat = q - z[:, None] * bend.normal
        s = np.linalg.norm(flat, axis=1)
        ang = np.mod(np.arctan2(flat @ np.cross(bend.normal, bend.e1), flat @ bend.e1), 2 * np.pi)
        cols.append((ang <= bend.angle) & (np.hypot(s - bend.bend_radius, z) < bend.radius - INSIDE_MARGIN_M))
    return np.stack(cols, axis=1) if cols else np.zeros((len(points), 0), bool)


def cast_to_wall(origin, dirs, tubes: list[Tube], bends: list[Bend]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points (n, 3) where rays from `origin` along unit `dirs` (n, 3) meet the wall, whether they do, and
    the shape met (n,): an index into tubes + bends, -1 for none."""
    origin = np.asarray(origin, float)
    dirs = np.atleast_2d(np.asarray(dirs, float))
    shapes = [(_tube_exit, s) for s in tubes] + [(Bend.wall_exit, s) for s in bends]
    shape = np.full(len(dirs), -1)
    if not shapes:
        return np.full((len(dirs), 3), np.nan), np.zeros(len(dirs), bool), shape
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
        shape[take] = j[take]
        todo &= ~take & np.isfinite(tk)
        if not todo.any():
            break
    ok = np.isfinite(best)
    return origin + np.where(ok, best, np.nan)[:, None] * dirs, ok, shape


__all__ = ["Tube", "Bend", "wall_shapes", "in_sight", "thicker", "cast_to_wall"]
