"""The route of a network result: its wall pieces (straight sections, in the order passed) joined at the
junction passes between them (run.json `wall_pieces`, `straight_sections`, `junction_passes`)."""

from __future__ import annotations

import numpy as np

from pipemap.errors import PipemapError
from pipemap.inspection.route import Route
from pipemap.inspection.route_build import Joint, Leg, build_route
from pipemap.inspection.up import estimate_up


def legs_and_joints(pieces: list[dict], sections: list[dict], passes: list[dict]) -> tuple[list[Leg], list[Joint]]:
    """The straight legs (one per wall piece that unrolls, in order) and the junction passes between them: the
    pass whose keyframes lie after one leg's section and before the next one's; `gap` where there is none. An elbow
    pass with the axes its solve found (`axes`) joins by them at its vertex (its `centroid`)."""
    span = section_spans(sections)
    legs = [Leg(str(p["name"]), np.asarray(p["start"], float), np.asarray(p["end"], float))
            for p in pieces if p.get("unroll", True) and p.get("kind", "line") == "line"]
    joints = []
    for a, b in zip(legs, legs[1:]):
        lo, hi = span.get(a.name, (None, None))[1], span.get(b.name, (None, None))[0]
        found = None
        if lo is not None and hi is not None:
            found = next((j for j in passes if int(j.get("first_keyframe", -1)) >= lo
                          and int(j.get("last_keyframe", 10**9)) <= hi), None)
        if found is None:
            joints.append(Joint(f"{a.name}-{b.name}", "gap"))
            continue
        bend, axes = found.get("bend_radius_m"), found.get("axes")
        elbow = found.get("type") == "elbow"
        joints.append(Joint(str(found["id"]), str(found.get("type", "tee")),
                            np.asarray(found["centroid"], float) if not elbow or axes is not None else None,
                            float(bend) if bend is not None else float("nan"),
                            _unit_axes(axes, found["id"]) if elbow and axes is not None else None))
    return legs, joints


def section_spans(sections: list[dict]) -> dict[str, tuple[int, int]]:
    """Each straight section's (first, last) keyframe by its wall piece's name (S<number>)."""
    return {f"S{s['section']}": (int(s["first_keyframe"]), int(s["last_keyframe"])) for s in sections}


def _unit_axes(axes, name) -> np.ndarray:
    """An elbow pass's solved `axes` as two unit vectors (2, 3)."""
    a = np.asarray(axes, float)
    n = np.linalg.norm(a, axis=-1, keepdims=True) if a.shape == (2, 3) else None
    if n is None or not np.all(np.isfinite(a)) or np.any(n < 1e-9):
        raise PipemapError("axes must be two non-zero 3-vectors", "run.json", f"junction_passes {name}")
    return a / n


def network_route(pieces: list[dict], sections: list[dict], passes: list[dict], poses: np.ndarray, radius: float,
                  up_choice="image") -> Route | None:
    """The route of a network result and its 12 o'clock estimate (keyframe poses T_wc (K, 4, 4)); None without
    a straight piece or where the cameras cover none of it."""
    legs, joints = legs_and_joints(pieces, sections, passes)
    if not legs or not len(poses):
        return None
    starts = np.array([leg.start for leg in legs])
    ends = np.array([leg.end for leg in legs])
    up, record = estimate_up(poses[:, :3, :3], poses[:, :3, 3], starts, ends, radius, up_choice)
    route = build_route(legs, joints, poses[0, :3, 3], _route_end(legs[-1], sections, poses), up, radius, record)
    return route if route.segments else None


def _route_end(leg: Leg, sections: list[dict], poses: np.ndarray) -> np.ndarray:
    """The camera centre the route runs to: of the last leg's section's cameras, the one farthest along the leg.
    That is the last camera, unless the robot turned back in that pipe (a crawler that drives in and reverses out
    ends where it began, and a route to its last camera would hold none of the pipe)."""
    first, last = section_spans(sections).get(leg.name, (len(poses) - 1, len(poses) - 1))
    C = poses[max(first, 0):min(last, len(poses) - 1) + 1, :3, 3]
    if not len(C):
        return poses[-1, :3, 3]
    return C[int(np.argmax((C - leg.start) @ leg.direction))]


__all__ = ["legs_and_joints", "network_route", "section_spans"]
