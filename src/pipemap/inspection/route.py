"""The route: the pipe axis the robot followed, as an ordered list of straight and bent segments with chainage.

Chainage is the distance along the axis from the route's start (the first keyframe's projection on the first
straight piece's axis), through junctions and along the arcs of elbows. The clock position of a point is the
angle around the axis, 0 at 12 o'clock (the segment's `up` across the local axis) and increasing clockwise
looking along the direction of survey: the same sense as the unrolled images' phi (docs/formats.md).

`Route.to_route(points)` gives (chainage, clock, radial distance, segment) of world points, and
`Route.from_route` goes back.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipemap.errors import PipemapError
from pipemap.output import atomic_write_text

FORMAT = "pipemap-route/1"
TWO_PI = 2 * np.pi
SIGHT_RADII = 10.0  # how far along the pipe from the camera a located wall point may lie
NODE_TOLERANCE_M = 1e-3  # route.json keeps junction chainage to 0.1 mm, segment ends to 1 um
PASS_TOLERANCE_RADII = 1.0  # where the route passes a place twice, the passes that fit this well compete
POINTS_AT_ONCE = 1 << 18  # to_route's chunk of points (every segment's candidates of each are held)


@dataclass(frozen=True)
class RouteSegment:
    """A straight (`line`) or bent (`arc`) piece of the route's axis from `start` to `end`.

    chainage_start / chainage_end: chainage at either end; up: the world direction of 12 o'clock (its
    component across the local axis); name: the wall piece (S2) or elbow (E1) it follows. An arc turns
    anticlockwise about `normal` around `centre` at `bend_radius` by `angle` radians."""

    kind: str
    name: str
    start: np.ndarray
    end: np.ndarray
    chainage_start: float
    chainage_end: float
    up: np.ndarray
    centre: np.ndarray | None = None
    normal: np.ndarray | None = None

    @property
    def length(self) -> float:
        return self.chainage_end - self.chainage_start

    @property
    def bend_radius(self) -> float:
        return float(np.linalg.norm(self.start - self.centre)) if self.kind == "arc" else np.inf

    @property
    def angle(self) -> float:
        return self.length / self.bend_radius if self.kind == "arc" else 0.0

    def _arc_basis(self) -> tuple[np.ndarray, np.ndarray]:
        e1 = (self.start - self.centre) / self.bend_radius
        return e1, np.cross(self.normal, e1)

    def axis_at(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Axis points and unit tangents (n, 3) at distances s (n,) from `start` (extrapolated past the ends)."""
        s = np.atleast_1d(np.asarray(s, float))
        if self.kind == "line":
            u = _unit(self.end - self.start)
            return self.start + s[:, None] * u, np.broadcast_to(u, (len(s), 3)).copy()
        e1, e2 = self._arc_basis()
        a = (s / self.bend_radius)[:, None]
        return self.centre + self.bend_radius * (np.cos(a) * e1 + np.sin(a) * e2), -np.sin(a) * e1 + np.cos(a) * e2

    def clock_frame(self, tangents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(e_up, e_cw) (n, 3): 12 and 3 o'clock across each tangent, looking along it."""
        e_up = self.up - (tangents @ self.up)[:, None] * tangents
        e_up /= np.linalg.norm(e_up, axis=1, keepdims=True)
        return e_up, np.cross(tangents, e_up)

    def local(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(s from start, clock rad in [0, 2 pi), radial distance, overshoot past the ends) of points (n, 3)."""
        p = np.asarray(points, float)
        if self.kind == "line":
            _, u = self.axis_at([0.0])
            s = (p - self.start) @ u[0]
        else:
            e1, e2 = self._arc_basis()
            q = p - self.centre
            a = np.arctan2(q @ e2, q @ e1)
            a = np.where(a < -0.5 * (TWO_PI - self.angle), a + TWO_PI, a)  # the far side counts from whichever end
            s = a * self.bend_radius
        axis, t = self.axis_at(s)
        w = p - axis
        e_up, e_cw = self.clock_frame(t)
        clock = np.mod(np.arctan2(np.einsum("ij,ij->i", w, e_cw), np.einsum("ij,ij->i", w, e_up)), TWO_PI)
        over = np.maximum(np.maximum(-s, s - self.length), 0.0)
        return s, clock, np.linalg.norm(w, axis=1), over

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "name": self.name, "start": _list(self.start), "end": _list(self.end),
             "chainage_start_m": round(float(self.chainage_start), 6),
             "chainage_end_m": round(float(self.chainage_end), 6), "up": _list(self.up)}
        if self.kind == "arc":
            d.update(centre=_list(self.centre), normal=_list(self.normal),
                     bend_radius_m=round(self.bend_radius, 6), angle_deg=round(float(np.degrees(self.angle)), 4))
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "RouteSegment":
        arc = d.get("kind", "line") == "arc"
        return cls("arc" if arc else "line", str(d["name"]), _vec(d["start"]), _vec(d["end"]),
                   float(d["chainage_start_m"]), float(d["chainage_end_m"]), _vec(d["up"]),
                   _vec(d["centre"]) if arc else None, _vec(d["normal"]) if arc else None)


@dataclass(frozen=True)
class Route:
    """Ordered route segments (chainage increasing, each starting where the one before ends), the pipe
    radius, how 12 o'clock was found (`up_source`, a short record for route.json) and the junctions passed
    as (id, type, chainage)."""

    segments: tuple[RouteSegment, ...]
    radius: float
    up_source: dict
    nodes: tuple[tuple[str, str, float], ...] = ()

    @property
    def length(self) -> float:
        return self.segments[-1].chainage_end if self.segments else 0.0

    def to_route(self, points, wall: bool = True, near_chainage=None, segment=None):
        """(chainage m, clock deg in [0, 360), radial distance m, segment index) of world points (n, 3).

        A wall point's coordinates are those along the pipe whose wall it lies on: where that is known (the wall
        piece a ray met), pass its segment as `segment` (-1 where unknown), so that a point in a tee's stub, on
        the through pipe's wall beyond the route's turn, gets that pipe's chainage and clock. Otherwise:

        Each point belongs to the segment it lies nearest inside: beyond its ends counts as distance, and
        for wall points (`wall`) so does the distance of the radial offset from the radius. The route's
        first and last segments reach on past its ends. Where the route passes a place twice (a loop),
        `near_chainage` (n,) (the camera's) leaves out passes out of its sight.

        Points are taken POINTS_AT_ONCE at a time: every segment's candidates of ten million map points
        at once took 3 GB."""
        p = np.atleast_2d(np.asarray(points, float))
        n = len(p)
        forced = None if segment is None else np.broadcast_to(np.asarray(segment, int), (n,))
        if forced is not None and (forced >= 0).all():
            return self._on_segments(p, forced)
        near = None if near_chainage is None else np.broadcast_to(np.asarray(near_chainage, float), (n,))
        parts = [self._located(p[a:a + POINTS_AT_ONCE], wall, None if near is None else near[a:a + POINTS_AT_ONCE],
                               None if forced is None else forced[a:a + POINTS_AT_ONCE])
                 for a in range(0, max(n, 1), POINTS_AT_ONCE)]
        return tuple(np.concatenate(part) for part in zip(*parts))

    def _on_segments(self, p: np.ndarray, segment: np.ndarray):
        """to_route of points whose segment is known."""
        chain, clock, rho = np.empty(len(p)), np.empty(len(p)), np.empty(len(p))
        for i in np.unique(segment):
            rows = np.flatnonzero(segment == i)
            for a in range(0, len(rows), POINTS_AT_ONCE):
                part = rows[a:a + POINTS_AT_ONCE]
                seg = self.segments[i]
                s, clock[part], rho[part], _ = seg.local(p[part])
                chain[part] = s + seg.chainage_start
        return chain, np.degrees(clock), rho, np.asarray(segment, int).copy()

    def _located(self, points, wall: bool, near_chainage, forced):
        chain, clock_all, rho_all, cost = self._candidates(points, wall)
        n = chain.shape[1]
        if near_chainage is not None:
            # A camera sees the wall within a few radii along the pipe: passes farther from its own chainage
            # than SIGHT_RADII are no candidates (unless nothing else is); of the rest the best fit wins.
            gap = np.abs(chain - near_chainage)
            near = np.where(gap <= SIGHT_RADII * self.radius, cost, np.inf)
            best = np.argmin(np.where(np.isfinite(near).any(axis=0), near, cost), axis=0)
        else:
            best = np.argmin(cost, axis=0)
        if forced is not None:
            best = np.where(forced >= 0, forced, best)
        cols = np.arange(n)
        return chain[best, cols], np.degrees(clock_all[best, cols]), rho_all[best, cols], best

    def _candidates(self, points, wall: bool):
        """Chainage, clock (rad), radial distance and misfit (segments, n) of points on every segment."""
        p = np.atleast_2d(np.asarray(points, float))
        n, k = len(p), len(self.segments)
        chain, clock_all, rho_all, cost = (np.empty((k, n)) for _ in range(4))
        for i, seg in enumerate(self.segments):
            s, clock, rho, over = seg.local(p)
            if i == 0:
                over = np.where(s < 0, 0.0, over)
            if i == k - 1:
                over = np.where(s > seg.length, 0.0, over)
            off = np.abs(rho - self.radius) if wall else np.maximum(rho - self.radius, 0.0)
            chain[i], clock_all[i], rho_all[i], cost[i] = s + seg.chainage_start, clock, rho, over + off
        return chain, clock_all, rho_all, cost

    def follow(self, positions) -> np.ndarray:
        """Chainage of camera centres (n, 3) in the order they were taken: where the route passes a place
        twice, each takes the pass nearest the one before (the first: the smallest misfit)."""
        chain, _, _, cost = self._candidates(positions, wall=False)
        ok = cost <= cost.min(axis=0) + PASS_TOLERANCE_RADII * self.radius
        out = np.empty(chain.shape[1])
        prev = None
        for i in range(len(out)):
            cand = np.flatnonzero(ok[:, i])
            j = cand[np.argmin(cost[cand, i])] if prev is None else cand[np.argmin(np.abs(chain[cand, i] - prev))]
            out[i] = prev = chain[j, i]
        return out

    def segments_named(self, names, near_chainage) -> np.ndarray:
        """Index (n,) of the segment with each name (-1: none); where the route passes one twice, the pass
        whose chainage is nearest `near_chainage`."""
        names = np.atleast_1d(np.asarray(names, dtype=object))
        near = np.broadcast_to(np.asarray(near_chainage, float), names.shape)
        out = np.full(len(names), -1)
        for i, (name, c) in enumerate(zip(names, near)):
            cand = [k for k, seg in enumerate(self.segments) if seg.name == name]
            if cand:
                out[i] = min(cand, key=lambda k: _gap(self.segments[k], c))
        return out

    def segment_at(self, chainage) -> np.ndarray:
        """Index of the segment holding each chainage (the first or last beyond the route's ends)."""
        starts = np.array([seg.chainage_start for seg in self.segments])
        return np.clip(np.searchsorted(starts, np.asarray(chainage, float), side="right") - 1, 0, len(starts) - 1)

    def from_route(self, chainage, clock_deg, radial=None, segment=None) -> np.ndarray:
        """World points (n, 3) at chainage, clock position and radial distance (default: the radius)."""
        c = np.atleast_1d(np.asarray(chainage, float))
        clock = np.radians(np.broadcast_to(np.asarray(clock_deg, float), c.shape))
        rho = np.broadcast_to(np.asarray(self.radius if radial is None else radial, float), c.shape)
        idx = self.segment_at(c) if segment is None else np.broadcast_to(np.asarray(segment, int), c.shape)
        out = np.empty((len(c), 3))
        for i in np.unique(idx):
            m = idx == i
            seg = self.segments[i]
            axis, t = seg.axis_at(c[m] - seg.chainage_start)
            e_up, e_cw = seg.clock_frame(t)
            out[m] = axis + rho[m, None] * (np.cos(clock[m])[:, None] * e_up + np.sin(clock[m])[:, None] * e_cw)
        return out

    def nodes_around(self, index: int) -> tuple[str, str]:
        """(from node, to node) of segment `index`: the junctions (or `start` / `end`) either side of a line; an
        elbow's arc lies inside the elbow, so both are the elbow's id."""
        seg = self.segments[index]
        if seg.kind == "arc":
            return seg.name, seg.name
        before = [j for j, _, c in self.nodes if c <= seg.chainage_start + NODE_TOLERANCE_M]
        after = [j for j, _, c in self.nodes if c >= seg.chainage_end - NODE_TOLERANCE_M]
        return (before[-1] if before else "start"), (after[0] if after else "end")

    def to_dict(self) -> dict:
        return {"format": FORMAT, "radius_m": self.radius, "length_m": round(self.length, 6),
                "up_estimate": self.up_source,
                "segments": [s.to_dict() for s in self.segments],
                "junctions": [{"id": j, "type": t, "chainage_m": round(c, 4)} for j, t, c in self.nodes]}

    @classmethod
    def from_dict(cls, d: dict, where: str = "route.json") -> "Route":
        if d.get("format") != FORMAT:
            raise PipemapError(f"expected format {FORMAT!r}, found {d.get('format')!r}", where, "format")
        try:
            segs = tuple(RouteSegment.from_dict(s) for s in d["segments"])
            nodes = tuple((str(j["id"]), str(j.get("type", "")), float(j["chainage_m"]))
                          for j in d.get("junctions", []))
            return cls(segs, float(d["radius_m"]), dict(d.get("up_estimate") or {}), nodes)
        except (KeyError, TypeError, ValueError) as exc:
            raise PipemapError(f"malformed route: {exc}", where) from None


def frame_chainage(frame_count: int, keyframe_frames, keyframe_chainage) -> np.ndarray:
    """Chainage of every frame of the recording: the keyframes' own, linear in frame index between them, NaN
    before the first and after the last keyframe."""
    f = np.asarray(keyframe_frames, float)
    out = np.full(frame_count, np.nan)
    if len(f):
        idx = np.arange(frame_count)
        inside = (idx >= f[0]) & (idx <= f[-1])
        out[inside] = np.interp(idx[inside], f, np.asarray(keyframe_chainage, float))
    return out


def route_segment_of(route: Route, piece) -> int:
    """The route segment that follows a wall piece (by name; else the one nearest its middle)."""
    for i, seg in enumerate(route.segments):
        if seg.name == piece.name:
            return i
    return int(route.to_route((piece.start + piece.end) / 2, wall=False)[3][0])


def piece_start_chainage(route: Route, piece) -> float:
    """Chainage of a wall piece's axis start on its route segment: h along the piece is at this + h."""
    i = route_segment_of(route, piece)
    seg = route.segments[i]
    if seg.kind == "arc":
        return float(route.to_route(piece.start, wall=False, segment=[i])[0][0])
    return float(seg.chainage_start + (piece.start - seg.start) @ piece.axis)


def write_route(path: Path, route: Route) -> None:
    atomic_write_text(Path(path), json.dumps(route.to_dict(), indent=2) + "\n")


def read_route(path: Path) -> Route:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise PipemapError("no route.json (results written before pipemap-route/1 lack it)", path) from None
    except (OSError, ValueError) as exc:
        raise PipemapError(f"cannot read: {exc}", path) from None
    if not isinstance(data, dict):
        raise PipemapError("expected a JSON object", path)
    return Route.from_dict(data, str(path))


def _gap(seg: RouteSegment, chainage: float) -> float:
    return max(seg.chainage_start - chainage, chainage - seg.chainage_end, 0.0)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _list(v) -> list[float]:
    return [round(float(x), 7) for x in v]


def _vec(v) -> np.ndarray:
    a = np.asarray(v, float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"expected 3 finite numbers, got {v!r}")
    return a


__all__ = ["Route", "RouteSegment", "FORMAT", "write_route", "read_route", "frame_chainage", "route_segment_of",
           "piece_start_chainage"]
