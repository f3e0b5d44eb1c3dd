"""Loop closure (fisheye paper III-E): revisited pipe -> pose pairs -> metric edges -> pose graph.

Choosing candidates. The paper needs no place recognition: knowing the start section and
counting left/right turns at the tees tells which physical pipe each straight section is, and
two poses of the same pipe at about equal distances l_i, l_j to the tee centroid at its end are
a candidate pair. Here the same decision is made from the mapped geometry: two sections are one
pipe when their fitted axes are nearly collinear (angle below `same_pipe_angle_deg`, offset across
the pipe below `same_pipe_offset_radii` radii) and overlap along the axis by `min_overlap_m`.

Why this gives the answer turn counting gives. Two visits of one pipe map to one axis up to the
odometry's drift between the visits. Two different pipes cannot both pass: parallel pipes' axes
lie at least a diameter apart (their walls cannot overlap); pipes on one line are separated by
the tee between them, so they do not overlap along the axis; any other two pipes of a tee network
meet at a large angle. So as long as the drift between visits is far below a section length along
the pipe (no false overlap across a tee), below the offset threshold across it, and below the
angle threshold in heading, the geometric test and turn counting pick the same pairs -- and the
geometric test needs neither the start section nor a record of the turns.

The tee at the end of a pipe is found once per visit (each pass of a tee is its own junction in
the map); l_i is measured to visit i's own tee and l_j to visit j's, so drift between the visits
does not enter the pairing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from pipemap.backend.place_match import LoopEdge, relative_pose
from pipemap.backend.pose_graph import PoseEdge, optimise_pose_graph, temporal_edges
from pipemap.camera import CameraModel
from pipemap.config import LoopClosureSettings, Settings
from pipemap.geometry.cylinder import Cylinder
from pipemap.geometry.se3 import as_rt, compose, invert, world_to_camera


@dataclass(frozen=True)
class StraightSection:
    """A straight section of the map: keyframes first..last (inclusive) and its fitted axis in world."""

    first: int
    last: int
    origin: np.ndarray  # (3,) a point on the axis
    direction: np.ndarray  # (3,) unit axis direction

    def __post_init__(self):
        d = np.asarray(self.direction, float)
        object.__setattr__(self, "origin", np.asarray(self.origin, float))
        object.__setattr__(self, "direction", d / np.linalg.norm(d))
        if self.last < self.first:
            raise ValueError(f"section keyframes {self.first}..{self.last} are empty")


@dataclass(frozen=True)
class TeeJunction:
    """A pass through a T-intersection: its centroid in world and the sections it joins."""

    centroid: np.ndarray
    sections: tuple[int, ...]


@dataclass(frozen=True)
class LoopCandidate:
    i: int  # keyframe on the earlier visit
    j: int  # keyframe on the later visit
    section_i: int
    section_j: int
    l_i: float  # distance to the tee at the section's end (or position along the axis without one)
    l_j: float


@dataclass
class LoopClosureResult:
    poses: np.ndarray  # (N, 4, 4) corrected T_wc
    candidates: list[LoopCandidate]
    edges: list[tuple[LoopCandidate, LoopEdge]]  # the candidates whose relative pose was measured
    seconds: dict = field(default_factory=dict)
    junction_edges: int = 0  # loop edges from tees passed twice (junction_loops)

    def summary(self) -> dict:
        return {"candidates": len(self.candidates), "edges": len(self.edges), "junction_edges": self.junction_edges,
                "inliers": [e.inliers for _, e in self.edges],
                "rms_deg": [float(np.degrees(e.rms_rad)) for _, e in self.edges], "seconds": self.seconds}


def _positions(poses) -> np.ndarray:
    return as_rt(poses)[1]


def same_pipe(a: StraightSection, b: StraightSection, positions: np.ndarray, radius: float,
              settings: LoopClosureSettings) -> tuple[float, float] | None:
    """The overlap (lo, hi) along a's axis of two sections that are one pipe, else None."""
    cos = abs(float(a.direction @ b.direction))
    if np.degrees(np.arccos(min(cos, 1.0))) > settings.same_pipe_angle_deg:
        return None
    pa, pb = positions[a.first:a.last + 1], positions[b.first:b.last + 1]
    sa, sb = (pa - a.origin) @ a.direction, (pb - a.origin) @ a.direction
    lo, hi = max(sa.min(), sb.min()), min(sa.max(), sb.max())
    if hi - lo < settings.min_overlap_m:
        return None
    # Offset of each axis from the other, where the two visits overlap.
    mid = a.origin + 0.5 * (lo + hi) * a.direction
    on_b = b.origin + ((mid - b.origin) @ b.direction) * b.direction
    offset = np.linalg.norm(np.cross(on_b - a.origin, a.direction))
    if offset > settings.same_pipe_offset_radii * radius:
        return None
    return float(lo), float(hi)


def _end_tee(a: int, b: int, sections, junctions, same_m: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The centroids, one per visit, of the same tee at an end of pipe a / b: the pair closest along
    the axis, if they lie within `same_m` of each other along it. None when the visits share no tee
    (one reached the tee at the pipe's one end, the other only the tee at its other end)."""
    axis = sections[a]
    ta = [j.centroid for j in junctions if a in j.sections]
    tb = [j.centroid for j in junctions if b in j.sections]
    if not ta or not tb:
        return None
    best = min(((abs(float((ca - cb) @ axis.direction)), k, m) for k, ca in enumerate(ta) for m, cb in enumerate(tb)),
               key=lambda x: x[0])
    if best[0] > same_m:
        return None
    return np.asarray(ta[best[1]], float), np.asarray(tb[best[2]], float)


def loop_candidates(sections: list[StraightSection], junctions: list[TeeJunction], poses, radius: float,
                    settings: LoopClosureSettings | None = None) -> list[LoopCandidate]:
    """Pose pairs (i earlier, j later) in the same physical pipe at l_i ~ l_j, up to
    `candidates_per_section` per pair of visits, spread along their overlap."""
    s = settings or LoopClosureSettings()
    positions = _positions(poses)
    order = sorted(range(len(sections)), key=lambda k: sections[k].first)
    out: list[LoopCandidate] = []
    for x, a in enumerate(order):
        for b in order[x + 1:]:
            overlap = same_pipe(sections[a], sections[b], positions, radius, s)
            if overlap is None:
                continue
            out += _pair_poses(a, b, sections, junctions, positions, overlap, s, radius)
    return out


def _pair_poses(a, b, sections, junctions, positions, overlap, s, radius) -> list[LoopCandidate]:
    sa, sb = sections[a], sections[b]
    ka, kb = np.arange(sa.first, sa.last + 1), np.arange(sb.first, sb.last + 1)
    tees = _end_tee(a, b, sections, junctions, s.same_junction_radii * radius)
    if tees is None:
        # No tee to measure from: positions along the axis, in the drifted map, and only where they overlap.
        la, lb = (positions[ka] - sa.origin) @ sa.direction, (positions[kb] - sa.origin) @ sa.direction
        ka, la = ka[(la >= overlap[0]) & (la <= overlap[1])], la[(la >= overlap[0]) & (la <= overlap[1])]
        kb, lb = kb[(lb >= overlap[0]) & (lb <= overlap[1])], lb[(lb >= overlap[0]) & (lb <= overlap[1])]
        if len(ka) == 0 or len(kb) == 0:
            return []
    else:
        # Each visit measured from its own pass of the tee: equal l is the same place whatever the drift
        # in between, and a pose beyond the other visit's reach finds no partner within the tolerance.
        la, lb = np.linalg.norm(positions[ka] - tees[0], axis=1), np.linalg.norm(positions[kb] - tees[1], axis=1)
    order = np.argsort(lb)
    lb_sorted = lb[order]
    right = np.minimum(np.searchsorted(lb_sorted, la), len(lb_sorted) - 1)
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(lb_sorted[left] - la) <= np.abs(lb_sorted[right] - la), left, right)
    gap = np.abs(lb_sorted[nearest] - la)
    ok = np.nonzero(gap < s.pairing_tolerance_m)[0]
    if len(ok) == 0:
        return []
    ok = ok[np.argsort(la[ok])]
    pick = ok[np.unique(np.round(np.linspace(0, len(ok) - 1, min(s.candidates_per_section, len(ok)))).astype(int))]
    return [LoopCandidate(int(ka[p]), int(kb[order[nearest[p]]]), a, b, float(la[p]), float(lb_sorted[nearest[p]]))
            for p in pick]


def cylinder_in_camera(section: StraightSection, pose, radius: float) -> Cylinder:
    """The section's wall in the frame of the camera at `pose` (T_wc)."""
    R, t = as_rt(pose)
    return Cylinder(world_to_camera(R, t, section.origin), R.T @ section.direction, radius)


def close_loops(camera: CameraModel, poses, sections: list[StraightSection], junctions: list[TeeJunction],
                image_of: Callable[[int], np.ndarray], radius: float, settings: Settings | None = None,
                seed: int = 0, extra_edges: tuple[PoseEdge, ...] | list[PoseEdge] = ()) -> LoopClosureResult:
    """Candidates -> metric loop edges -> pose graph with temporal edges -> corrected keyframe poses.

    `poses` (N, 4, 4) are the keyframes' T_wc from odometry, `image_of(k)` returns keyframe k's image.
    Pairs whose relative pose cannot be measured are dropped; `extra_edges` (loop edges measured otherwise:
    junction_loops) join them; without any edge the poses come back as they were.
    """
    settings = settings or Settings()
    lc = settings.loop_closure
    poses = np.asarray(poses, float)
    t0 = time.perf_counter()
    if not lc.enabled:
        return LoopClosureResult(poses.copy(), [], [])
    candidates = loop_candidates(sections, junctions, poses, radius, lc)
    measured: list[tuple[LoopCandidate, LoopEdge]] = []
    for c in candidates:
        edge = relative_pose(camera, image_of(c.i), image_of(c.j),
                             cylinder_in_camera(sections[c.section_i], poses[c.i], radius),
                             cylinder_in_camera(sections[c.section_j], poses[c.j], radius), settings, (seed, c.i, c.j))
        if edge is not None:
            measured.append((c, edge))
    t1 = time.perf_counter()
    if not measured and not extra_edges:
        return LoopClosureResult(poses.copy(), candidates, [], {"relative_pose": t1 - t0, "pose_graph": 0.0})
    edges = temporal_edges(poses, lc.odometry_sigma_m, np.radians(lc.odometry_sigma_deg))
    edges += [PoseEdge.from_covariance(c.i, c.j, e.T_ij, e.covariance, loop=True) for c, e in measured]
    edges += list(extra_edges)
    kernel = None if lc.robust_kernel == "none" else lc.robust_kernel
    corrected = optimise_pose_graph(poses, edges, kernel=kernel, kernel_width=lc.kernel_width)
    return LoopClosureResult(corrected, candidates, measured,
                             {"relative_pose": t1 - t0, "pose_graph": time.perf_counter() - t1}, len(extra_edges))


def reanchor(points, owner_pose_before, owner_pose_after) -> np.ndarray:
    """Move points (M, 3) (scene points, junction centroids) rigidly with the pose each hangs from:
    X' = T_after T_before^-1 X, with one pose (4, 4) for all points or one per point (M, 4, 4)."""
    X = np.asarray(points, float)
    Rb, tb = as_rt(owner_pose_before)
    Ra, ta = as_rt(owner_pose_after)
    Rd, td = compose(Ra, ta, *invert(Rb, tb))
    return np.einsum("...ij,...j->...i", Rd, X) + td


__all__ = ["StraightSection", "TeeJunction", "LoopCandidate", "LoopClosureResult", "LoopEdge", "same_pipe",
           "loop_candidates", "cylinder_in_camera", "relative_pose", "close_loops", "reanchor"]
