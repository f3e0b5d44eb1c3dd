"""The network pipeline's map: what the stages after the VO take and return.

Keyframes with their poses, the scene points with their tracks and the keyframe that first saw each
(its owner), the straight sections with their cylinders and bent axes, the junctions with their
centres, and at the end the wall pieces the appearance maps sample. A correction found after some
keyframe — the tee model's rigid move of the section beyond a tee, loop closure's corrected poses — is
one method here, so every piece that hangs from a pose moves with it in the same way: points with
their owner, sections and junctions with the keyframes they start at.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from pipemap.backend.loop_closure import reanchor
from pipemap.backend.network_map import MappedJunction, MappedSection, camera_extent
from pipemap.frontend.tracks import Keyframe
from pipemap.geometry.cylinder import Cylinder


def first_seen(keyframes: list[Keyframe], tids_sorted: np.ndarray) -> np.ndarray:
    """For each track id in `tids_sorted`, the first keyframe that observes it (the last keyframe for an id
    that none observes)."""
    out = np.full(len(tids_sorted), len(keyframes) - 1, np.int64)
    for k in range(len(keyframes) - 1, -1, -1):
        ids = keyframes[k].track_ids
        p = np.searchsorted(tids_sorted, ids)
        ok = p < len(tids_sorted)
        ok[ok] = tids_sorted[p[ok]] == ids[ok]
        out[p[ok]] = k
    return out


@dataclass
class PipeMap:
    keyframes: list[Keyframe]
    poses: np.ndarray  # (N, 4, 4) T_wc of the keyframes, metres
    points: np.ndarray  # (M, 3) world
    point_tracks: np.ndarray  # (M,) track ids
    owners: np.ndarray  # (M,) the keyframe that first saw each point
    sections: list[MappedSection]
    junctions: list[MappedJunction]
    wall_pieces: list[dict] = field(default_factory=list)  # the straight pieces of wall the maps sample, once placed

    @classmethod
    def build(cls, keyframes: list[Keyframe], poses: np.ndarray, points: np.ndarray, point_tracks: np.ndarray,
              sections: list[MappedSection], junctions: list[MappedJunction]) -> "PipeMap":
        order = np.argsort(point_tracks)
        owners = np.empty(len(point_tracks), np.int64)
        owners[order] = first_seen(keyframes, np.asarray(point_tracks)[order])
        return cls(keyframes, np.array(poses, float), np.array(points, float), np.asarray(point_tracks), owners,
                   sections, junctions)

    def copy(self) -> "PipeMap":
        """A map whose arrays, sections and junctions can change without touching this one (the keyframes,
        which no stage changes, are shared)."""
        return PipeMap(self.keyframes, self.poses.copy(), self.points.copy(), self.point_tracks, self.owners,
                       copy.deepcopy(self.sections), copy.deepcopy(self.junctions), copy.deepcopy(self.wall_pieces))

    def move_after(self, k: int, T: np.ndarray) -> None:
        """Move everything from keyframe k + 1 on rigidly by T (4, 4, world -> world): the poses, the points
        those keyframes first saw, the sections and junctions that start there."""
        R, t = T[:3, :3], T[:3, 3]
        self.poses[k + 1:] = T @ self.poses[k + 1:]
        later = self.owners > k
        self.points[later] = self.points[later] @ R.T + t
        for m in self.sections:
            if m.first > k:
                m.cylinder, m.start, m.end = (moved_cylinder(T, c) for c in (m.cylinder, m.start, m.end))
                if m.bend is not None:  # knots are axial coordinates and move with the axis; offsets are world vectors
                    m.bend = (m.bend[0], m.bend[1] @ R.T)
                if m.cylinder is not None:
                    m.start_h, m.end_h = camera_extent(m.cylinder.axial(self.poses[m.first:m.last + 1, :3, 3]))
        for j in self.junctions:
            if j.first > k:
                j.centroid = R @ j.centroid + t
                j.branch = None if j.branch is None else R @ j.branch
                j.axes = None if j.axes is None else j.axes @ R.T

    def reanchor(self, poses: np.ndarray) -> None:
        """Corrected poses (N, 4, 4), not all by one rigid move (loop closure): each point moves rigidly with
        its owner, each junction centre (and an elbow's solved axes) with its nearest keyframe. The sections'
        cylinders are left to be fitted again to the moved points."""
        poses = np.asarray(poses, float)
        self.points = reanchor(self.points, self.poses[self.owners], poses[self.owners])
        for j in self.junctions:
            j.centroid = reanchor(j.centroid, self.poses[j.keyframe], poses[j.keyframe])
            turn = poses[j.keyframe, :3, :3] @ self.poses[j.keyframe, :3, :3].T
            if j.branch is not None:
                j.branch = turn @ j.branch
            if j.axes is not None:
                j.axes = j.axes @ turn.T
        self.poses = poses.copy()


def moved_cylinder(T: np.ndarray, c: Cylinder | None) -> Cylinder | None:
    """The cylinder moved rigidly by T (4, 4, world -> world); None stays None."""
    return None if c is None else Cylinder(T[:3, :3] @ c.origin + T[:3, 3], T[:3, :3] @ c.direction, c.radius)


__all__ = ["PipeMap", "first_seen", "moved_cylinder"]
