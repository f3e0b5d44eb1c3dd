"""An elbow's piece of pipe wall: the bent tube around the arc of its axis, in the trajectory's world frame.

The arc is the route's (inspection/route_build.py): tangent to the axes the elbow's solve found either side of its
bend (where it was solved with it; else the straight pieces' axes), leaving the first bend radius x tan(angle / 2)
before the vertex and joining the second as far after it, so that the wall is the torus the cameras through the bend
were solved against. The straight pieces end where the elbow's wall begins (`with_elbows`).

Wall coordinates, as on a straight piece (wall.py): h is metres along the arc's axis from `start` (0 there,
`length` = bend radius x angle at `end`: chainage along the elbow); phi is the angle around the local axis,
0 at 12 o'clock (`up` taken across the local tangent, as route.json's clock) and increasing clockwise looking
along the arc from start to end. A wall point is axis(h) + r (cos(phi) e_up(h) + sin(phi) e_cw(h)),
e_cw = tangent x e_up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from pipemap.errors import PipemapError
from pipemap.geometry.torus import TorusPiece
from pipemap.inspection.route import RouteSegment
from pipemap.mapping.wall import WallPiece, three_vectors

MAX_ARC_STEP_DEG = 5.0  # the axis polyline's step: its chord lies within r (1 - cos 2.5 deg) < 0.1 % r of the arc


@dataclass(frozen=True)
class ElbowPiece:
    """The wall of an elbow: the tube of `radius` around the arc from `start` that turns anticlockwise about the
    unit `normal` around `centre` by `angle_deg` (0 < angle < 180). up, unroll: as a straight WallPiece's."""

    name: str
    start: np.ndarray
    centre: np.ndarray
    normal: np.ndarray
    angle_deg: float
    radius: float
    up: np.ndarray
    unroll: bool = True

    kind: ClassVar[str] = "arc"
    # A bend's inner wall can hide its own far side from a camera inside it (a straight tube's cannot).
    wall_in_sight_from_inside: ClassVar[bool] = False

    def __post_init__(self):
        where = f"wall piece {self.name!r}"
        vals = three_vectors(self, ("start", "centre", "normal", "up"), where)
        try:
            angle, r = float(self.angle_deg), float(self.radius)
        except (TypeError, ValueError):
            raise PipemapError("angle_deg and radius must be numbers", where) from None
        if not (math.isfinite(r) and r > 0):
            raise PipemapError(f"radius must be a positive number of metres, got {self.radius!r}", where)
        if not (0 < angle < 180):
            raise PipemapError(f"an elbow turns by more than 0 and less than 180 deg, got {angle!r}", where)
        arm = vals["start"] - vals["centre"]
        n = vals["normal"] / max(np.linalg.norm(vals["normal"]), 1e-300)
        if not np.linalg.norm(arm) > r or abs(arm @ n) > 1e-6 * np.linalg.norm(arm) + 1e-9:
            raise PipemapError("start must lie in the bend's plane, farther from the centre than the radius", where)
        for key, v in vals.items():
            object.__setattr__(self, key, n if key == "normal" else v)
        object.__setattr__(self, "angle_deg", angle)
        object.__setattr__(self, "radius", r)
        object.__setattr__(self, "unroll", bool(self.unroll))
        _, t = self.axis_at(np.linspace(0.0, self.length, 64))
        across = self.up - (t @ self.up)[:, None] * t
        if np.linalg.norm(across, axis=1).min() < 1e-6 * np.linalg.norm(self.up):
            raise PipemapError("up is parallel to the arc's axis somewhere: 12 o'clock is undefined there", where)

    @property
    def bend_radius(self) -> float:
        return float(np.linalg.norm(self.start - self.centre))

    @property
    def angle(self) -> float:
        return math.radians(self.angle_deg)

    @property
    def length(self) -> float:
        """Length of the axis along the arc."""
        return self.bend_radius * self.angle

    @property
    def along_stretch(self) -> float:
        """How much longer the outside of the bend is than its axis: a grid fine enough there is fine everywhere."""
        return (self.bend_radius + self.radius) / self.bend_radius

    @property
    def segment(self) -> RouteSegment:
        """The arc as a route segment from chainage 0 (its axis maths and clock convention)."""
        e1 = (self.start - self.centre) / self.bend_radius
        turn = math.cos(self.angle) * e1 + math.sin(self.angle) * np.cross(self.normal, e1)
        end = self.centre + self.bend_radius * turn
        return RouteSegment("arc", self.name, self.start, end, 0.0, self.length, self.up, self.centre, self.normal)

    @property
    def end(self) -> np.ndarray:
        return self.segment.end

    @property
    def torus(self) -> TorusPiece:
        return TorusPiece(self.centre, self.normal, (self.start - self.centre) / self.bend_radius, self.bend_radius,
                          self.angle, self.radius)

    def axis_at(self, h) -> tuple[np.ndarray, np.ndarray]:
        """Axis points and unit tangents (n, 3) at h (n,)."""
        return self.segment.axis_at(h)

    def wall_points(self, h, phi) -> np.ndarray:
        """World points (len(h), len(phi), 3) of the wall at h (rows) and phi (columns)."""
        seg = self.segment
        axis, t = seg.axis_at(h)
        e_up, e_cw = seg.clock_frame(t)
        phi = np.asarray(phi, float)
        ring = np.cos(phi)[None, :, None] * e_up[:, None, :] + np.sin(phi)[None, :, None] * e_cw[:, None, :]
        return axis[:, None, :] + self.radius * ring

    def wall_coordinates(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(h, phi in [0, 2 pi), distance from the axis) of world points (..., 3)."""
        p = np.asarray(points, float)
        h, phi, rho, _ = self.segment.local(p.reshape(-1, 3))
        return h.reshape(p.shape[:-1]), phi.reshape(p.shape[:-1]), rho.reshape(p.shape[:-1])

    def contains(self, points, margin: float = 0.0, h_margin: float = 0.0) -> np.ndarray:
        """Points (..., 3) deeper than margin inside the solid tube, within the arc widened by h_margin."""
        return self.torus.contains(points, margin, h_margin)

    def exit(self, X: np.ndarray, D: np.ndarray, s: np.ndarray, tol: float) -> np.ndarray:
        """Line parameter where c + s D, now at X, leaves the solid widened by tol; s where X is not inside it."""
        return s + self.torus.solid_exit(X, D, tol)

    def holds_segment(self, X: np.ndarray, P: np.ndarray, tol: float) -> np.ndarray:
        """(n,) segments X -> P surely inside the solid widened by tol (TorusPiece.holds_segment)."""
        return self.torus.holds_segment(X, P, tol)

    def axis_distance(self, point) -> float:
        """Distance from a point to the arc of the axis (clamped to its ends)."""
        q = self.torus.local(point)
        a = math.atan2(q[1], q[0])
        a = a + 2 * math.pi if a < -0.5 * (2 * math.pi - self.angle) else a  # the far side: the nearer end
        a = min(max(a, 0.0), self.angle)
        foot = self.bend_radius * np.array([math.cos(a), math.sin(a), 0.0])
        return float(np.linalg.norm(q - foot))

    def axis_polyline(self) -> np.ndarray:
        """Points (n, 3) along the axis, every MAX_ARC_STEP_DEG at the most."""
        steps = max(1, math.ceil(self.angle_deg / MAX_ARC_STEP_DEG))
        return self.axis_at(np.linspace(0.0, self.length, steps + 1))[0]

    def to_dict(self) -> dict:
        def vec(v):
            return [round(float(x), 7) for x in v]
        return {"name": self.name, "kind": "arc", "start": vec(self.start), "end": vec(self.end),
                "centre": vec(self.centre), "normal": vec(self.normal), "bend_radius": round(self.bend_radius, 7),
                "angle_deg": round(self.angle_deg, 6), "radius": self.radius, "up": [float(v) for v in self.up],
                "unroll": self.unroll}

    @classmethod
    def from_dict(cls, d: dict, where: str = "wall piece") -> "ElbowPiece":
        missing = [k for k in ("name", "start", "centre", "normal", "angle_deg", "radius", "up") if k not in d]
        if missing:
            raise PipemapError(f"missing {', '.join(missing)}", where)
        try:
            return cls(str(d["name"]), d["start"], d["centre"], d["normal"], d["angle_deg"], d["radius"], d["up"],
                       bool(d.get("unroll", True)))
        except PipemapError as exc:
            raise PipemapError(exc.message, where) from None

    @classmethod
    def from_route_segment(cls, seg: RouteSegment, radius: float) -> "ElbowPiece":
        return cls(seg.name, seg.start, seg.centre, seg.normal, math.degrees(seg.angle), radius, seg.up, True)


def piece_from_dict(d: dict, where: str = "wall piece"):
    """A run.json `wall_pieces` record (or an unrolled sidecar's axis): a straight WallPiece, or an ElbowPiece
    for `kind: arc`."""
    if isinstance(d, dict) and d.get("kind", "line") == "arc":
        return ElbowPiece.from_dict(d, where)
    if isinstance(d, dict) and d.get("kind", "line") != "line":
        raise PipemapError(f"unknown kind {d.get('kind')!r} (line or arc)", where)
    return WallPiece.from_dict(d, where)


def with_elbows(pieces: list[dict], route) -> list[dict]:
    """run.json `wall_pieces` with an elbow piece for each arc of the route (inspection.Route), after the
    straight piece before it; the straight pieces either side end where the arc begins and ends (the projections of
    the route's tangent points on their axes; their own ends came from the elbow's vertex and angle, a few
    millimetres off)."""
    out = [dict(p) for p in pieces]
    by_name = {p["name"]: p for p in out}
    segs = route.segments
    for i, seg in enumerate(segs):
        if seg.kind != "arc":
            continue
        elbow = ElbowPiece.from_route_segment(seg, route.radius).to_dict()
        before = by_name.get(segs[i - 1].name) if i > 0 and segs[i - 1].kind == "line" else None
        after = by_name.get(segs[i + 1].name) if i + 1 < len(segs) and segs[i + 1].kind == "line" else None
        if before is not None:
            _move_end(before, "end", seg.start)
        if after is not None:
            _move_end(after, "start", seg.end)
        out.insert(out.index(before) + 1 if before is not None else len(out), elbow)
    return out


def _move_end(piece: dict, key: str, to: np.ndarray) -> None:
    """Move a straight piece's start or end along its axis to the projection of `to` (its bend knots, h from the
    start, move with the start); a move that would leave it shorter than half a radius is not made."""
    a, b = np.asarray(piece["start"], float), np.asarray(piece["end"], float)
    u = (b - a) / np.linalg.norm(b - a)
    h = float((np.asarray(to, float) - a) @ u)
    length = float(np.linalg.norm(b - a))
    if (key == "end" and h < 0.5 * piece["radius"]) or (key == "start" and length - h < 0.5 * piece["radius"]):
        return
    piece[key] = (a + h * u).round(6).tolist()
    if key == "start" and piece.get("bend"):
        piece["bend"] = {"h": [round(v - h, 6) for v in piece["bend"]["h"]], "offset": piece["bend"]["offset"]}


__all__ = ["ElbowPiece", "piece_from_dict", "with_elbows", "MAX_ARC_STEP_DEG"]
