"""The pipe network of formats.md (`ground_truth/network.yaml`): straight and bent segments, junctions.

`pipemap-network/2` adds junction types (tee, cross, elbow with its angle and bend radius) and arc
segments (an elbow's bent pipe: a torus piece around a circular axis). `/1` files are still read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from pipemap.errors import PipemapError
from pipemap.yamlfile import read_yaml

FORMAT = "pipemap-network/2"
READ_FORMATS = ("pipemap-network/1", FORMAT)
JUNCTION_TYPES = ("tee", "cross", "elbow")
_ARC_TOL_M = 1e-6  # written keys that repeat an arc's geometry must agree with it this well
_ARC_TOL_DEG = 1e-5


@dataclass(frozen=True)
class Segment:
    """A pipe piece of the network radius: a cylinder around start -> end, or, with `centre`, an arc
    (an elbow's bent pipe, a torus piece) from start to end around the centre of curvature, turning
    by less than 180 deg. `junction` names the elbow an arc belongs to."""

    id: str
    start: np.ndarray
    end: np.ndarray
    centre: np.ndarray | None = None
    junction: str | None = None

    @property
    def kind(self) -> str:
        return "line" if self.centre is None else "arc"

    @property
    def is_arc(self) -> bool:
        return self.centre is not None

    @property
    def bend_radius(self) -> float:
        """The arc's radius of curvature of its axis (metres); inf for a straight segment."""
        return float(np.linalg.norm(self.start - self.centre)) if self.is_arc else np.inf

    @property
    def angle(self) -> float:
        """How far the axis turns along the segment (radians): 0 for a straight one."""
        if not self.is_arc:
            return 0.0
        a, b = self.start - self.centre, self.end - self.centre
        return float(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b))

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of an arc's plane; the arc runs anticlockwise about it from start to end."""
        n = np.cross(self.start - self.centre, self.end - self.centre)
        return n / np.linalg.norm(n)

    @property
    def length(self) -> float:
        """Chainage from start to end along the axis (the arc's length for an arc)."""
        if self.is_arc:
            return self.bend_radius * self.angle
        return float(np.linalg.norm(self.end - self.start))

    @property
    def axis(self) -> np.ndarray:
        """A straight segment's unit direction."""
        if self.is_arc:
            raise ValueError(f"segment {self.id} is an arc: it has no single axis direction")
        return (self.end - self.start) / self.length

    def axis_points(self, h) -> tuple[np.ndarray, np.ndarray]:
        """Axis points and unit tangents (n, 3) at chainages h (n,) from `start` (not clamped)."""
        h = np.atleast_1d(np.asarray(h, float))
        if not self.is_arc:
            u = self.axis
            return self.start + h[:, None] * u, np.broadcast_to(u, (len(h), 3)).copy()
        rho = self.bend_radius
        e1 = (self.start - self.centre) / rho
        e2 = np.cross(self.normal, e1)  # the tangent at start
        a = (h / rho)[:, None]
        pos = self.centre + rho * (np.cos(a) * e1 + np.sin(a) * e2)
        return pos, -np.sin(a) * e1 + np.cos(a) * e2

    @property
    def tangents(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions of travel at start and at end."""
        _, t = self.axis_points([0.0, self.length])
        return t[0], t[1]

    @property
    def vertex(self) -> np.ndarray:
        """Where the straight axes either side meet: an arc's elbow centre (its end for a line)."""
        if not self.is_arc:
            return self.end.copy()
        return self.start + self.tangents[0] * self.bend_radius * np.tan(self.angle / 2)

    def to_dict(self) -> dict:
        d = {"id": self.id}
        if self.is_arc:
            d["kind"] = "arc"
        d["start"], d["end"] = _list(self.start), _list(self.end)
        if self.is_arc:
            d.update(centre=_list(self.centre), bend_radius_m=self.bend_radius,
                     angle_deg=float(np.degrees(self.angle)))
            if self.junction is not None:
                d["junction"] = self.junction
        return d


@dataclass(frozen=True)
class Junction:
    """Where pipe axes meet: a tee or cross (its pipes' axes meet at the centroid) or an elbow (the
    centroid is the vertex where the straight axes either side meet; the arc between them turns by
    `angle_deg` at `bend_radius_m`)."""

    id: str
    type: str
    centroid: np.ndarray
    angle_deg: float | None = None
    bend_radius_m: float | None = None

    def to_dict(self) -> dict:
        d = {"id": self.id, "type": self.type, "centroid": _list(self.centroid)}
        if self.angle_deg is not None:
            d["angle_deg"] = float(self.angle_deg)
        if self.bend_radius_m is not None:
            d["bend_radius_m"] = float(self.bend_radius_m)
        return d


@dataclass(frozen=True)
class PipeNetwork:
    radius_m: float
    segments: tuple[Segment, ...]
    junctions: tuple[Junction, ...] = ()
    visits: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)

    def junction(self, jid: str) -> Junction:
        for j in self.junctions:
            if j.id == jid:
                return j
        raise KeyError(jid)

    def visited_junctions(self) -> list[Junction]:
        return [self.junction(j) for j in self.visits]

    def straight_pieces(self, max_sagitta_m: float = 1e-4) -> tuple[Segment, ...]:
        """The segments with every arc replaced by chords whose mid-points lie within `max_sagitta_m` of it
        (for code that knows only cylinders). Chords overlap by r tan(kink) at their joints, so that their
        union has no wedge-shaped gap on the bend's outside; their walls lie within about
        max_sagitta_m + r kink^2 of the torus."""
        out: list[Segment] = []
        for s in self.segments:
            if not s.is_arc:
                out.append(s)
                continue
            step = 2 * np.arccos(max(0.0, 1 - max_sagitta_m / s.bend_radius))
            n = max(1, int(np.ceil(s.angle / step)))
            pts, _ = s.axis_points(np.linspace(0.0, s.length, n + 1))
            over = self.radius_m * np.tan(s.angle / n)
            for k in range(n):
                u = (pts[k + 1] - pts[k]) / np.linalg.norm(pts[k + 1] - pts[k])
                a = pts[k] - (over * u if k > 0 else 0.0)
                b = pts[k + 1] + (over * u if k < n - 1 else 0.0)
                out.append(Segment(f"{s.id}#{k}", a, b))
        return tuple(out)

    def to_dict(self) -> dict:
        d = {
            "format": FORMAT,
            "radius_m": float(self.radius_m),
            "segments": [s.to_dict() for s in self.segments],
            "junctions": [j.to_dict() for j in self.junctions],
            "visits": list(self.visits),
        }
        d.update(self.extra)
        return d


def _list(v) -> list[float]:
    return [float(x) for x in v]


def _vec3(value, path, key) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise PipemapError("expected a list of 3 numbers", path, key) from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise PipemapError("expected a list of 3 finite numbers", path, key)
    return v


def _number(value, path, key, positive: bool = True) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise PipemapError("not a number", path, key) from None
    if not np.isfinite(x) or (positive and not x > 0):
        raise PipemapError("must be a positive number" if positive else "must be a finite number", path, key)
    return x


def _segment(s, path, key: str, version: int) -> Segment:
    if not isinstance(s, dict) or "id" not in s:
        raise PipemapError("expected {id, start, end}", path, key)
    kind = str(s.get("kind", "line"))
    if kind not in ("line", "arc"):
        raise PipemapError(f"unknown segment kind {kind!r} (expected line or arc)", path, key + ".kind")
    start, end = _vec3(s.get("start"), path, key + ".start"), _vec3(s.get("end"), path, key + ".end")
    if kind == "line":
        seg = Segment(str(s["id"]), start, end)
        if seg.length <= 0:
            raise PipemapError("segment has zero length", path, key)
        return seg
    if version < 2:
        raise PipemapError("arc segments need format pipemap-network/2", path, key + ".kind")
    seg = Segment(str(s["id"]), start, end, _vec3(s.get("centre"), path, key + ".centre"),
                  None if s.get("junction") is None else str(s["junction"]))
    r0, r1 = np.linalg.norm(start - seg.centre), np.linalg.norm(end - seg.centre)
    if not r0 > 0 or abs(r0 - r1) > _ARC_TOL_M * max(1.0, r0):
        raise PipemapError(f"start and end must lie at one distance from the centre ({r0:.6f} and {r1:.6f} m)",
                           path, key)
    if not 0 < np.degrees(seg.angle) < 180 - _ARC_TOL_DEG or np.linalg.norm(np.cross(start - seg.centre,
                                                                                      end - seg.centre)) <= 0:
        raise PipemapError("an arc must turn by more than 0 and less than 180 degrees", path, key)
    for name, value, tol in (("bend_radius_m", seg.bend_radius, _ARC_TOL_M * max(1.0, r0)),
                             ("angle_deg", np.degrees(seg.angle), _ARC_TOL_DEG)):
        if name in s and abs(_number(s[name], path, f"{key}.{name}") - value) > tol:
            raise PipemapError(f"{s[name]} disagrees with the arc's start, end and centre ({value:.6f})", path,
                               f"{key}.{name}")
    return seg


def _junction(j, path, key: str, version: int) -> Junction:
    if not isinstance(j, dict) or "id" not in j:
        raise PipemapError("expected {id, type, centroid}", path, key)
    jtype = str(j.get("type", "tee"))
    if version >= 2 and jtype not in JUNCTION_TYPES:
        raise PipemapError(f"unknown junction type {jtype!r} (expected one of {', '.join(JUNCTION_TYPES)})", path,
                           key + ".type")
    angle = bend = None
    if jtype == "elbow" and version >= 2:
        for name in ("angle_deg", "bend_radius_m"):
            if name not in j:
                raise PipemapError("an elbow needs angle_deg and bend_radius_m", path, f"{key}.{name}")
        angle = _number(j["angle_deg"], path, key + ".angle_deg")
        bend = _number(j["bend_radius_m"], path, key + ".bend_radius_m")
        if not angle < 180:
            raise PipemapError("an elbow turns by less than 180 degrees", path, key + ".angle_deg")
    return Junction(str(j["id"]), jtype, _vec3(j.get("centroid"), path, key + ".centroid"), angle, bend)


def _check_elbow_arcs(segments, junctions, path) -> None:
    """An arc that names its elbow must turn by the elbow's angle at its bend radius, about its vertex."""
    by_id = {j.id: j for j in junctions}
    for i, s in enumerate(segments):
        if not s.is_arc or s.junction is None:
            continue
        key = f"segments[{i}].junction"
        j = by_id.get(s.junction)
        if j is None or j.type != "elbow":
            raise PipemapError(f"{s.junction!r} names no elbow", path, key)
        if (abs(np.degrees(s.angle) - j.angle_deg) > _ARC_TOL_DEG
                or abs(s.bend_radius - j.bend_radius_m) > _ARC_TOL_M * max(1.0, s.bend_radius)
                or np.linalg.norm(s.vertex - j.centroid) > _ARC_TOL_M * max(1.0, s.bend_radius)):
            raise PipemapError(f"arc {s.id} disagrees with elbow {j.id} (angle, bend radius or centroid)", path, key)


def load_network(path: str | Path) -> PipeNetwork:
    """Read network.yaml (`pipemap-network/1` or `/2`); every problem is one PipemapError naming the file."""
    path = Path(path)
    data = read_yaml(path, "network file")
    if data.get("format") not in READ_FORMATS:
        raise PipemapError(f"expected '{FORMAT}' (or '{READ_FORMATS[0]}'), found {data.get('format')!r}", path,
                           "format")
    version = READ_FORMATS.index(data["format"]) + 1
    if "radius_m" not in data:
        raise PipemapError("missing", path, "radius_m")
    try:
        radius = float(data["radius_m"])
    except (TypeError, ValueError):
        raise PipemapError("not a number", path, "radius_m") from None
    if not radius > 0:
        raise PipemapError("must be positive", path, "radius_m")
    segments = [_segment(s, path, f"segments[{i}]", version) for i, s in enumerate(data.get("segments") or [])]
    junctions = [_junction(j, path, f"junctions[{i}]", version) for i, j in enumerate(data.get("junctions") or [])]
    _check_elbow_arcs(segments, junctions, path)
    ids = {j.id for j in junctions}
    visits = tuple(str(v) for v in (data.get("visits") or []))
    for v in visits:
        if v not in ids:
            raise PipemapError(f"visit {v!r} names no junction", path, "visits")
    known = {"format", "radius_m", "segments", "junctions", "visits"}
    extra = {k: v for k, v in data.items() if k not in known}
    return PipeNetwork(radius, tuple(segments), tuple(junctions), visits, extra)


def save_network(path: str | Path, network: PipeNetwork) -> None:
    Path(path).write_text(yaml.safe_dump(network.to_dict(), sort_keys=False, default_flow_style=None))
