"""Loop edges from a junction passed twice: both passes measured the same tee, so the same frame.

Image loop closure needs the camera to see one stretch of pipe twice in the same direction. A route
that comes back to a tee along another of its pipes (round a loop, into the tee along its stem where
it first passed straight through) sees no such stretch, yet the tee itself is one rigid thing: its
centre I, the axis of the pipe that runs through it and the direction of its branch form a frame
(x along the branch from I, z along the through axis, y = z x x). Each pass measures that frame
relative to its nearest keyframe: a turning pass from the tee model's two cylinders and its through
pipe, a straight-through pass from its through axis and its side opening. Two passes of one tee (their
centres within `same_junction_radii` radii, the pairing `name_junctions` makes) therefore measure the
relative pose of their keyframes, T_k1k2 = L1 L2^-1 with L = T_wk^-1 F, an edge for the pose graph.

A tee maps onto itself by a half turn about its branch (the through axis reversed), so the second
frame is taken with its z axis on the first's side. Passes whose branch or through directions disagree
by more than AGREE_DEG (a cross seen through different branches, a wrong through pipe) give no edge.
"""

from __future__ import annotations

import numpy as np

from pipemap.backend.elbow import bend_of
from pipemap.backend.network_map import MappedJunction
from pipemap.backend.pipe_map import PipeMap
from pipemap.backend.pose_graph import PoseEdge
from pipemap.config import LoopClosureSettings

AGREE_DEG = 20.0


def tee_frame(pipe_map: PipeMap, j: MappedJunction) -> np.ndarray | None:
    """The tee's frame F (4, 4, world) as this pass measured it, or None (an elbow, no through pipe known)."""
    if j.type == "elbow":
        return None
    by_number = {m.number: m for m in pipe_map.sections}
    red, blue = by_number.get(j.before), by_number.get(j.after)
    end = red.end if red is not None else None
    start = blue.start if blue is not None else None
    if j.method == "side-opening" and j.branch is not None and (end or start) is not None:
        through, branch = (end or start).direction, np.asarray(j.branch, float)
    elif j.method == "tee-model" and j.through in ("red", "blue") and end is not None and start is not None:
        bend = bend_of(end, start, j.centroid)
        # red runs on: the camera turned from it into the branch; blue runs on: it came out of the branch
        through, branch = (bend.d1, bend.d2) if j.through == "red" else (bend.d2, -bend.d1)
    else:
        return None
    z = through / np.linalg.norm(through)
    x = branch - (branch @ z) * z
    if np.linalg.norm(x) < 0.5:  # the branch runs nearly along the through axis: no frame
        return None
    x /= np.linalg.norm(x)
    F = np.eye(4)
    F[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    F[:3, 3] = j.centroid
    return F


def _agree(F1: np.ndarray, F2: np.ndarray) -> np.ndarray | None:
    """F2 turned by the tee's half turn where that puts its through axis on F1's side; None if the two
    frames disagree beyond AGREE_DEG in branch or through direction."""
    F2 = F2.copy()
    if F1[:3, 2] @ F2[:3, 2] < 0:
        F2[:3, 1:3] *= -1.0
    limit = np.cos(np.radians(AGREE_DEG))
    if F1[:3, 0] @ F2[:3, 0] < limit or F1[:3, 2] @ F2[:3, 2] < limit:
        return None
    return F2


def junction_identity_edges(pipe_map: PipeMap, radius: float, lc: LoopClosureSettings) -> list[PoseEdge]:
    """A pose-graph edge between each later pass of a tee and its first pass."""
    frames = [(j, tee_frame(pipe_map, j)) for j in pipe_map.junctions]
    cov = np.diag([lc.junction_sigma_m ** 2] * 3 + [np.radians(lc.junction_sigma_deg) ** 2] * 3)
    edges: list[PoseEdge] = []
    firsts: list[tuple[MappedJunction, np.ndarray]] = []
    for j, F in frames:
        if F is None:
            continue
        near = lc.same_junction_radii * radius
        same = [(a, Fa) for a, Fa in firsts if np.linalg.norm(a.centroid - j.centroid) < near]
        if not same:
            firsts.append((j, F))
            continue
        a, Fa = same[0]
        F2 = _agree(Fa, F)
        if F2 is None or a.keyframe == j.keyframe:
            continue
        L1 = np.linalg.inv(pipe_map.poses[a.keyframe]) @ Fa
        L2 = np.linalg.inv(pipe_map.poses[j.keyframe]) @ F2
        edges.append(PoseEdge.from_covariance(a.keyframe, j.keyframe, L1 @ np.linalg.inv(L2), cov, loop=True))
    return edges


__all__ = ["tee_frame", "junction_identity_edges", "AGREE_DEG"]
