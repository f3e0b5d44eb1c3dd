"""Loop closure on the mapped network (fisheye paper III-E), and what hangs from the corrected poses.

The mapped straight sections and tee passes go to `close_loops` (candidate pairs in a revisited
pipe, metric relative poses from the images, pose graph), with an edge for every tee passed twice
(`junction_loops`: both passes measured the same tee). The corrected keyframe poses then carry
what hangs from them: each scene point moves rigidly with the first keyframe that saw it, each tee
centre with its nearest keyframe; the sections' cylinders are fitted again afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from pipemap.backend.junction_loops import junction_identity_edges
from pipemap.backend.loop_closure import StraightSection, TeeJunction, close_loops
from pipemap.backend.pipe_map import PipeMap
from pipemap.camera.base import CameraModel
from pipemap.config import Settings


@dataclass
class RevisitReport:
    status: str  # "closed", "no revisit", "no edge measured", "disabled"
    candidates: int = 0
    edges: int = 0
    max_correction_m: float = 0.0
    seconds: float = 0.0
    details: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"status": self.status, "candidates": self.candidates, "edges": self.edges,
                "max_correction_m": round(self.max_correction_m, 6), "seconds": round(self.seconds, 3),
                **self.details}


def close_network_loops(pipe_map: PipeMap, camera: CameraModel, image_of: Callable[[int], np.ndarray],
                        radius: float, settings: Settings) -> tuple[PipeMap, RevisitReport]:
    """The map with its poses corrected where the route revisits a pipe (`PipeMap.reanchor`: points and
    junction centres follow), and the report; the sections' cylinders are for the caller to fit again."""
    if not settings.loop_closure.enabled:
        return pipe_map, RevisitReport("disabled")
    usable = [m for m in pipe_map.sections if m.cylinder is not None]
    positions = pipe_map.poses[:, :3, 3]
    lc_sections: list[StraightSection] = []
    ends: dict[int, tuple[int, int]] = {}  # section number: its first and last leg among lc_sections
    for m in usable:
        legs = section_legs(positions[m.first:m.last + 1], m.cylinder.origin, m.cylinder.direction,
                            settings.loop_closure.min_overlap_m)
        ends[m.number] = (len(lc_sections), len(lc_sections) + len(legs) - 1)
        lc_sections += [StraightSection(m.first + a, m.first + b, m.cylinder.origin, m.cylinder.direction)
                        for a, b in legs]
    lc_junctions = [TeeJunction(j.centroid, tuple(ends[n][k] for n, k in ((j.before, 1), (j.after, 0)) if n in ends))
                    for j in pipe_map.junctions]
    extra = junction_identity_edges(pipe_map, radius, settings.loop_closure) if settings.loop_closure.junction_edges \
        else []
    res = close_loops(camera, pipe_map.poses, lc_sections, lc_junctions, image_of, radius, settings, settings.seed,
                      extra)
    if not res.candidates and not extra:
        return pipe_map, RevisitReport("no revisit", seconds=sum(res.seconds.values()))
    if not res.edges and not extra:
        return pipe_map, RevisitReport("no edge measured", len(res.candidates), 0, seconds=sum(res.seconds.values()))
    out = pipe_map.copy()
    out.reanchor(res.poses)
    shift = float(np.max(np.linalg.norm(out.poses[:, :3, 3] - pipe_map.poses[:, :3, 3], axis=1)))
    return out, RevisitReport("closed", len(res.candidates), len(res.edges) + len(extra), shift,
                              sum(res.seconds.values()), res.summary())


def section_legs(positions: np.ndarray, origin: np.ndarray, direction: np.ndarray, turn_back_m: float
                 ) -> list[tuple[int, int]]:
    """(first, last) rows of `positions` (a section's keyframes, in order) driven one way along the axis: a leg
    ends where the robot turns back and then goes more than `turn_back_m` the other way. A crawler that reverses
    to look again visits its pipe twice within one section; each leg is then a visit the loop closure can pair
    with the others (the same wall seen from the same side, so its images match)."""
    h = (np.asarray(positions, float) - origin) @ direction
    legs, start, way, turn = [], 0, 0, 0
    for i in range(1, len(h)):
        if way == 0:  # which way this leg goes: once it is more than turn_back_m from its start
            way = int(np.sign(h[i] - h[start])) if abs(h[i] - h[start]) > turn_back_m else 0
            turn = i
        elif way * (h[i] - h[turn]) > 0:
            turn = i
        elif way * (h[turn] - h[i]) > turn_back_m:
            legs.append((start, turn))
            start, way = turn + 1, -way
            turn = int(start + np.argmax(way * h[start:i + 1]))
    legs.append((start, len(h) - 1))
    return legs


__all__ = ["RevisitReport", "close_network_loops", "section_legs"]
