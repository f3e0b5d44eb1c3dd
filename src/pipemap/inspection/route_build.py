"""Building a Route from the straight pipe axes the robot passed, in order, and the junctions between them.

Between two straight legs the route turns at a junction point J: the tee or cross centre where one is known,
else where the two axes pass closest (or, for nearly parallel legs, halfway between the first's end and the
second's start). Each leg ends at J's projection on its axis and the next one starts at J's projection on
its own (the axes miss each other by the millimetres of their fits; chainage runs on without a jump). At an
elbow with a known bend radius rho and turn theta the route follows the arc tangent to both axes: it leaves
the first axis rho tan(theta / 2) before the vertex and joins the second as far after it. Where the elbow's solve
found the axes either side of its bend (`Joint.axes`, with the vertex as `Joint.point`), the arc is tangent to
those instead: the cameras through the bend were solved against them, while the legs are the straight sections'
own axes, which may miss them by a few tenths of a degree. The legs then end and start at the projections of the
arc's ends (a few millimetres across; chainage runs on).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.inspection.route import Route, RouteSegment

PARALLEL_DEG = 5.0  # legs closer to parallel than this have no meaningful crossing point
MIN_TURN_DEG = 1.0  # an elbow turning less than this is followed as a corner


@dataclass(frozen=True)
class Leg:
    """A straight stretch of pipe axis, directed the way the robot went."""

    name: str
    start: np.ndarray
    end: np.ndarray

    @property
    def direction(self) -> np.ndarray:
        d = np.asarray(self.end, float) - self.start
        return d / np.linalg.norm(d)

    def project(self, p) -> np.ndarray:
        return self.start + ((np.asarray(p, float) - self.start) @ self.direction) * self.direction


@dataclass(frozen=True)
class Joint:
    """What joins leg k to leg k + 1: id and type of the junction (`gap` where none was found), its centre
    (for an elbow the vertex) or None, an elbow's bend radius (nan: unknown) and the unit directions (2, 3) of
    its solved axes into and out of the vertex `point` (None: the legs' own)."""

    id: str
    type: str
    point: np.ndarray | None = None
    bend_radius: float = float("nan")
    axes: np.ndarray | None = None


def closest_approach(a: Leg, b: Leg) -> np.ndarray | None:
    """The midpoint of the closest approach of the two axis lines; None when they are nearly parallel."""
    d1, d2 = a.direction, b.direction
    if np.degrees(np.arccos(np.clip(abs(d1 @ d2), 0.0, 1.0))) < PARALLEL_DEG:
        return None
    r = a.start - b.start
    bb, c, f = d1 @ d2, d1 @ r, d2 @ r
    den = 1.0 - bb * bb
    s = (bb * f - c) / den
    t = (f - bb * c) / den
    return 0.5 * (a.start + s * d1 + b.start + t * d2)


def build_route(legs: list[Leg], joints: list[Joint], first: np.ndarray, last: np.ndarray, up: np.ndarray,
                radius: float, up_source: dict) -> Route:
    """The route along `legs` (at least one) joined by `joints` (one fewer), from the projection of `first`
    (the first camera centre) on the first leg to that of `last` on the last."""
    if not legs:
        raise ValueError("a route needs at least one straight leg")
    if len(joints) != len(legs) - 1:
        raise ValueError(f"{len(legs)} legs need {len(legs) - 1} joints, got {len(joints)}")
    up = np.asarray(up, float)
    segments: list[RouteSegment] = []
    nodes: list[tuple[str, str, float]] = []
    entry = legs[0].project(first)
    chainage = 0.0
    for k, leg in enumerate(legs):
        if k == len(legs) - 1:
            exit_, arc, nxt = leg.project(last), None, None
        else:
            exit_, arc, nxt = _turn(leg, legs[k + 1], joints[k])
        length = max(float((exit_ - entry) @ leg.direction), 0.0)
        if length > 0:
            segments.append(RouteSegment("line", leg.name, entry, entry + length * leg.direction, chainage,
                                         chainage + length, up))
            chainage += length
        if nxt is None:
            continue
        j = joints[k]
        if arc is not None:
            start, centre, normal, angle, rho = arc
            e1 = (start - centre) / rho
            end = centre + rho * (np.cos(angle) * e1 + np.sin(angle) * np.cross(normal, e1))
            segments.append(RouteSegment("arc", j.id, start, end, chainage, chainage + rho * angle, up, centre,
                                         normal))
            nodes.append((j.id, j.type, chainage + 0.5 * rho * angle))
            chainage += rho * angle
        else:
            nodes.append((j.id, j.type, chainage))
        entry = nxt
    return Route(tuple(segments), float(radius), up_source, tuple(nodes))


def _turn(a: Leg, b: Leg, joint: Joint):
    """(where the route leaves leg a, the arc (start, centre, normal, angle, bend radius) or None, where it joins
    leg b)."""
    meet = closest_approach(a, b)
    point = joint.point if joint.point is not None else meet
    if point is None:  # parallel legs and no junction centre: halfway across the gap
        point = 0.5 * (a.end + b.start)
    solved = joint.axes is not None and joint.point is not None
    d1, d2 = (np.asarray(joint.axes[0], float), np.asarray(joint.axes[1], float)) if solved else (a.direction,
                                                                                                  b.direction)
    angle = float(np.arccos(np.clip(d1 @ d2, -1.0, 1.0)))
    rho = joint.bend_radius
    if joint.type == "elbow" and np.isfinite(rho) and rho > 0 and np.degrees(angle) >= MIN_TURN_DEG:
        tangent = rho * np.tan(angle / 2)
        if solved:
            start = point - tangent * d1
            leave, join = a.project(start), b.project(point + tangent * d2)
        else:
            vertex = meet if meet is not None else point
            leave = start = a.project(vertex) - tangent * d1
            join = b.project(vertex) + tangent * d2
        normal = np.cross(d1, d2)
        normal /= np.linalg.norm(normal)
        inward = d2 - (d2 @ d1) * d1
        centre = start + rho * inward / np.linalg.norm(inward)
        return leave, (start, centre, normal, angle, rho), join
    return a.project(point), None, b.project(point)


__all__ = ["Leg", "Joint", "build_route", "closest_approach"]
