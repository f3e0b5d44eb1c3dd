"""The pipe network of formats.md (`ground_truth/network.yaml`): straight segments and junctions."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from pipemap.errors import PipemapError
from pipemap.yamlfile import read_yaml

FORMAT = "pipemap-network/1"


@dataclass(frozen=True)
class Segment:
    """A straight pipe piece: a cylinder of the network radius around start -> end."""

    id: str
    start: np.ndarray
    end: np.ndarray

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    @property
    def axis(self) -> np.ndarray:
        return (self.end - self.start) / self.length


@dataclass(frozen=True)
class Junction:
    id: str
    type: str
    centroid: np.ndarray


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

    def to_dict(self) -> dict:
        d = {
            "format": FORMAT,
            "radius_m": float(self.radius_m),
            "segments": [
                {"id": s.id, "start": [float(v) for v in s.start], "end": [float(v) for v in s.end]}
                for s in self.segments
            ],
            "junctions": [
                {"id": j.id, "type": j.type, "centroid": [float(v) for v in j.centroid]} for j in self.junctions
            ],
            "visits": list(self.visits),
        }
        d.update(self.extra)
        return d


def _vec3(value, path, key) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise PipemapError("expected a list of 3 numbers", path, key) from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise PipemapError("expected a list of 3 finite numbers", path, key)
    return v


def load_network(path: str | Path) -> PipeNetwork:
    path = Path(path)
    data = read_yaml(path, "network file")
    if data.get("format") != FORMAT:
        raise PipemapError(f"expected '{FORMAT}', found {data.get('format')!r}", path, "format")
    try:
        radius = float(data["radius_m"])
    except KeyError:
        raise PipemapError("missing", path, "radius_m") from None
    except (TypeError, ValueError):
        raise PipemapError("not a number", path, "radius_m") from None
    if not radius > 0:
        raise PipemapError("must be positive", path, "radius_m")
    segments = []
    for i, s in enumerate(data.get("segments") or []):
        key = f"segments[{i}]"
        if not isinstance(s, dict) or "id" not in s:
            raise PipemapError("expected {id, start, end}", path, key)
        seg = Segment(str(s["id"]), _vec3(s.get("start"), path, key + ".start"),
                      _vec3(s.get("end"), path, key + ".end"))
        if seg.length <= 0:
            raise PipemapError("segment has zero length", path, key)
        segments.append(seg)
    junctions = []
    for i, j in enumerate(data.get("junctions") or []):
        key = f"junctions[{i}]"
        if not isinstance(j, dict) or "id" not in j:
            raise PipemapError("expected {id, type, centroid}", path, key)
        junctions.append(Junction(str(j["id"]), str(j.get("type", "tee")),
                                  _vec3(j.get("centroid"), path, key + ".centroid")))
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
