"""Which junction passes are junctions: the axis turns there, or a branch opens beside the camera's path.

The classification labels frames by how the dark far end of the pipe looks, so a distant tee ahead, or
a moment of flicker, makes a cluster of junction frames where nothing branches; and where the robot
drives straight through a real tee, the two straight sections' axes run on in one line and cannot say
where along it the tee is (`network_map` could only take the middle of the junction frames, which start
earlier before a tee than they end after it). So a pass whose axes turn by at least
STRAIGHT_THROUGH_DEG is a junction placed where they meet (or by the tee model); any other pass is one
only when the points the camera saw around it show a side branch (`side_opening`), which also places it;
without one it is dropped and reported, and the straight sections either side stay what they are.
A pass with a straight section on one side only (the run starts or ends in it) is kept as it is.

A pass whose axes turn is a tee when one pipe runs on past the point where they meet, a cross when
both do, and an elbow when none does (`elbow.pipe_beyond`) and its wall bends no tighter than three quarters of a pipe
diameter (`pass_type`); an elbow keeps the axes' meeting point
(its vertex) and their angle, gets its bend radius from the wall of the bend (`elbow.fit_bend_radius`),
and is not joined by the tee model, whose two cylinders meeting at a corner are not its shape.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.backend.elbow import ARC_MARGIN_DEG, bend_of, bend_residuals, fit_bend_radius, on_arc, pipe_beyond
from pipemap.backend.network_map import STRAIGHT_THROUGH_DEG, MappedJunction, section_points
from pipemap.backend.pipe_map import PipeMap
from pipemap.backend.side_opening import fit_side_opening
from pipemap.config import Settings


@dataclass
class DroppedPass:
    """A junction pass with no branch or bend to show for it."""

    id: str
    first: int  # keyframes of its junction section
    last: int
    angle_deg: float
    reason: str

    def to_dict(self) -> dict:
        return {"id": self.id, "first_keyframe": self.first, "last_keyframe": self.last,
                "angle_deg": round(self.angle_deg, 3), "reason": self.reason}


def _pass_points(pipe_map: PipeMap, j: MappedJunction, order: np.ndarray, tids: np.ndarray,
                 settings: Settings) -> np.ndarray:
    """The points seen by the pass's keyframes and as many either side as the tee model takes."""
    b = settings.bundle
    lo = max(0, j.first - b.tee_hold_keyframes)
    hi = min(len(pipe_map.keyframes) - 1, j.last + b.tee_attach_keyframes)
    return pipe_map.points[order[section_points(pipe_map.keyframes, lo, hi, tids)]]


def _end_cylinders(pipe_map: PipeMap, j: MappedJunction):
    by_number = {m.number: m for m in pipe_map.sections}
    red, blue = by_number.get(j.before), by_number.get(j.after)
    return (red.end if red else None), (blue.start if blue else None), red


def _opening(pipe_map: PipeMap, j: MappedJunction, order: np.ndarray, tids: np.ndarray, settings: Settings):
    """The side opening near a straight-through pass, from the points seen around it."""
    end, start, red = _end_cylinders(pipe_map, j)
    through = next((c for c in (end, start, red.cylinder if red else None) if c is not None), None)
    if through is None:
        return None
    b, e = settings.bundle, settings.evidence
    points = _pass_points(pipe_map, j, order, tids, settings)
    # near the junction frames: the tee model's centre of two parallel cylinders can lie anywhere along them
    guess = float(through.axial(pipe_map.poses[j.first:j.last + 1, :3, 3].mean(axis=0)))
    return fit_side_opening(points, through, guess, huber_m=b.huber_m, mad_k=b.mad_k,
                            outlier_passes=b.outlier_passes, reach_radii=e.opening_reach_radii,
                            min_points=e.opening_min_points, max_sigma_m=e.opening_max_sigma_radii * through.radius)


def weigh_junction_evidence(pipe_map: PipeMap, settings: Settings) -> tuple[PipeMap, list[DroppedPass]]:
    """The map with every straight-through pass placed from its side opening, and without the passes that
    show neither a turn nor an opening (returned, with why)."""
    out = pipe_map.copy()
    order = np.argsort(out.point_tracks)
    tids = out.point_tracks[order]
    kept, dropped = [], []
    for j in out.junctions:
        if j.before is None or j.after is None or not j.angle_deg < STRAIGHT_THROUGH_DEG:
            kept.append(j)
            continue
        opening = _opening(out, j, order, tids, settings)
        if opening is None:
            dropped.append(DroppedPass(j.id, j.first, j.last, j.angle_deg, "the axis runs straight on and no side "
                                       "opening shows in the points around it: not a junction"))
            continue
        j.centroid, j.method, j.type, j.opening = opening.centre, "side-opening", opening.kind, opening.to_dict()
        j.branch = opening.direction
        centres = out.poses[j.first:j.last + 1, :3, 3]
        j.keyframe = j.first + int(np.argmin(np.linalg.norm(centres - j.centroid, axis=1)))
        kept.append(j)
    out.junctions = kept
    return out, dropped


def type_turning_passes(pipe_map: PipeMap, radius: float, settings: Settings) -> PipeMap:
    """The map with every turning pass typed by the pipe that runs on past its vertex: one pipe, a tee; both,
    a cross; none, an elbow, with its bend radius where the bend's wall fixes it."""
    out = pipe_map.copy()
    order = np.argsort(out.point_tracks)
    tids = out.point_tracks[order]
    b, e = settings.bundle, settings.evidence
    for j in out.junctions:
        if j.before is None or j.after is None or not j.angle_deg >= STRAIGHT_THROUGH_DEG:
            continue
        end, start, _ = _end_cylinders(out, j)
        if end is None or start is None:
            continue
        points = _pass_points(out, j, order, tids, settings)
        bend = bend_of(end, start, j.centroid)
        rho = _bend_radius(points, bend, radius, settings)
        if np.isfinite(rho):  # a gentle bend's wall runs on past its vertex: it is not a pipe beyond it
            off = np.abs(bend_residuals(points, bend, rho, radius)[0]) > 4 * b.huber_m
            points = points[off | ~on_arc(points, bend, rho, margin_deg=-ARC_MARGIN_DEG)]
        beyond = pipe_beyond(points, end, start, bend, 4 * b.huber_m)
        kind = pass_type(beyond, rho, radius, e.opening_min_points)
        if kind == "elbow":
            j.type, j.method, j.angle_deg, j.bend_radius_m = "elbow", "elbow", bend.angle_deg, rho
        else:
            j.type = kind
    return out


def pass_type(beyond: tuple[int, int], rho: float, radius: float, min_points: int) -> str:
    """"tee", "cross" or "elbow" from the points on each pipe past the vertex (`elbow.pipe_beyond`) and the bend
    radius the wall was fitted with (nan: none). A bend's wall is a torus about its arc; the tightest elbows made
    (short radius) bend at one pipe diameter. The corner where two pipes meet fits one under the pipe's radius
    (0.7-0.8 of it at paper-loop's tees): a fit under three quarters of the diameter, halfway between the two, found
    a tee whose run-on pipe showed too few points to count (compressed footage: 22-26 of the 30 on paper-loop route
    A), not an elbow."""
    if min(beyond) >= min_points:
        return "cross"
    if max(beyond) >= min_points or (np.isfinite(rho) and rho < 1.5 * radius):
        return "tee"
    return "elbow"


def _bend_radius(points: np.ndarray, bend, radius: float, settings: Settings) -> float:
    b = settings.bundle
    fit = fit_bend_radius(points, bend, radius, huber_m=b.huber_m, mad_k=b.mad_k, outlier_passes=b.outlier_passes,
                          min_points=settings.evidence.opening_min_points)
    return float("nan") if fit is None else fit.bend_radius_m


def fit_elbow_bends(pipe_map: PipeMap, radius: float, settings: Settings) -> PipeMap:
    """The map with every elbow's angle and bend radius from its final end cylinders and points (after the
    tee model has joined its two pipes)."""
    out = pipe_map.copy()
    order = np.argsort(out.point_tracks)
    tids = out.point_tracks[order]
    for j in out.junctions:
        end, start, _ = _end_cylinders(out, j)
        if j.type != "elbow" or end is None or start is None or j.modelled:
            continue
        bend = bend_of(end, start, j.centroid)
        j.angle_deg = bend.angle_deg
        j.bend_radius_m = _bend_radius(_pass_points(out, j, order, tids, settings), bend, radius, settings)
    return out


__all__ = ["DroppedPass", "weigh_junction_evidence", "type_turning_passes", "pass_type", "fit_elbow_bends"]
