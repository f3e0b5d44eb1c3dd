"""The true chainage and clock of wall points, for judging `pipemap locate`: the route of the true camera centres
through ground_truth/network.yaml's straight segments (joined as the estimate's route is, arcs at elbows, 12
o'clock = world +z), and the route segment of every scene piece (a tee's stub: the through pipe it continues).
It reads the simulator's network only; the route geometry is the shared maths of inspection.route."""

from __future__ import annotations

import numpy as np

from pipemap.inspection.route import Route
from pipemap.inspection.route_build import Joint, Leg, build_route


def true_route(network, positions: np.ndarray, first: np.ndarray, last: np.ndarray) -> Route:
    """The route of the true camera centres (n, 3) through the network's straight segments."""
    lines = [s for s in network.segments if not s.is_arc]
    starts = np.array([s.start for s in lines])
    d = np.array([s.end - s.start for s in lines])
    q = positions[:, None, :] - starts[None]
    s = np.clip(np.einsum("kli,li->kl", q, d) / np.einsum("li,li->l", d, d), 0, 1)
    near = np.argmin(np.linalg.norm(q - s[..., None] * d[None], axis=2), axis=1)
    order, runs = [], []
    for k, seg in enumerate(near):  # visits of at least 5 frames, in order
        if runs and runs[-1][0] == seg:
            runs[-1][1].append(k)
        else:
            runs.append((seg, [k]))
    runs = [r for r in runs if len(r[1]) >= 5]
    for seg, ks in runs:
        if order and order[-1][0] == seg:
            order[-1][1].extend(ks)
        else:
            order.append((seg, list(ks)))
    legs = []
    for seg, ks in order:
        line = lines[seg]
        h = (positions[ks] - line.start) @ line.axis
        forward = h[-1] >= h[0]
        legs.append(Leg(line.id, line.start if forward else line.end, line.end if forward else line.start))
    arcs = [s for s in network.segments if s.is_arc]
    joints = []
    for a, b in zip(legs, legs[1:]):
        arc = next((c for c in arcs if np.linalg.norm(c.start - a.end) < 1e-6 and np.linalg.norm(c.end - b.start)
                    < 1e-6), None)
        joints.append(Joint(arc.id if arc else f"{a.name}-{b.name}", "elbow" if arc else "tee", None,
                            arc.bend_radius if arc else float("nan")))
    return build_route(legs, joints, first, last, np.array([0.0, 0.0, 1.0]), network.radius_m, {"method": "truth"})


def segment_of_piece(route: Route, network, piece_ids: list[str]) -> dict[str, str]:
    """Route segment name of every scene piece: its own, or for a piece the route does not follow (a stub), the
    route line whose axis it continues (within 1 mm and 0.1 deg)."""
    lines = {s.id: s for s in network.segments if not s.is_arc}
    names = {seg.name for seg in route.segments}
    out = {}
    for pid in piece_ids:
        if pid in names or pid not in lines:
            out[pid] = pid
            continue
        q = lines[pid]
        for seg in route.segments:
            if seg.kind != "line":
                continue
            u = (seg.end - seg.start) / np.linalg.norm(seg.end - seg.start)
            off = [np.linalg.norm((x - seg.start) - ((x - seg.start) @ u) * u) for x in (q.start, q.end)]
            if max(off) < 1e-3:
                out[pid] = seg.name
                break
    return out


__all__ = ["true_route", "segment_of_piece"]
