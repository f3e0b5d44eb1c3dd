"""Loop closure on the mapped network (fisheye paper III-E), and what hangs from the corrected poses.

The mapped straight sections and tee passes go to `close_loops` (candidate pairs in a revisited
pipe, metric relative poses from the images, pose graph). The corrected keyframe poses then carry
what hangs from them: each scene point moves rigidly with the first keyframe that saw it, each tee
centre with its nearest keyframe; the sections' cylinders are fitted again afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from pipemap.backend.loop_closure import StraightSection, TeeJunction, close_loops, reanchor
from pipemap.backend.network_map import MappedJunction, MappedSection
from pipemap.camera.base import CameraModel
from pipemap.config import Settings
from pipemap.frontend.tracks import Keyframe


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


def first_seen(keyframes: list[Keyframe], tids_sorted: np.ndarray) -> np.ndarray:
    """For each track id in `tids_sorted`, the first keyframe that observes it."""
    out = np.full(len(tids_sorted), len(keyframes) - 1, np.int64)
    for k in range(len(keyframes) - 1, -1, -1):
        ids = keyframes[k].track_ids
        p = np.searchsorted(tids_sorted, ids)
        ok = p < len(tids_sorted)
        ok[ok] = tids_sorted[p[ok]] == ids[ok]
        out[p[ok]] = k
    return out


def close_network_loops(camera: CameraModel, keyframes: list[Keyframe], poses: np.ndarray, points: np.ndarray,
                        point_tracks: np.ndarray, sections: list[MappedSection], junctions: list[MappedJunction],
                        image_of: Callable[[int], np.ndarray], radius: float, settings: Settings,
                        ) -> tuple[np.ndarray, np.ndarray, RevisitReport]:
    """(corrected poses, re-anchored points, report); junction centroids are moved in place."""
    if not settings.loop_closure.enabled:
        return poses, points, RevisitReport("disabled")
    usable = [m for m in sections if m.cylinder is not None]
    index = {m.number: i for i, m in enumerate(usable)}
    lc_sections = [StraightSection(m.first, m.last, m.cylinder.origin, m.cylinder.direction) for m in usable]
    lc_junctions = [TeeJunction(j.centroid, tuple(index[n] for n in (j.before, j.after) if n in index))
                    for j in junctions]
    res = close_loops(camera, poses, lc_sections, lc_junctions, image_of, radius, settings, settings.seed)
    if not res.candidates:
        return poses, points, RevisitReport("no revisit", seconds=sum(res.seconds.values()))
    if not res.edges:
        return poses, points, RevisitReport("no edge measured", len(res.candidates), 0,
                                            seconds=sum(res.seconds.values()))
    new = res.poses
    order = np.argsort(point_tracks)
    owner = np.empty(len(point_tracks), np.int64)
    owner[order] = first_seen(keyframes, point_tracks[order])
    moved = reanchor(points, poses[owner], new[owner])
    for j in junctions:
        j.centroid = reanchor(j.centroid, poses[j.keyframe], new[j.keyframe])
    shift = float(np.max(np.linalg.norm(new[:, :3, 3] - poses[:, :3, 3], axis=1)))
    return new, moved, RevisitReport("closed", len(res.candidates), len(res.edges), shift,
                                     sum(res.seconds.values()), res.summary())


__all__ = ["RevisitReport", "close_network_loops", "first_seen"]
