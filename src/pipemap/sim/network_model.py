"""Pipe networks as the renderer sees them: straight cylinders (pieces) of one internal radius.

A *run* is a chain of pieces between two junctions or ends (one straight pipe, possibly built
of several pieces that sag and are slightly misaligned at their joints). A tee is three runs
whose axes meet at the junction centroid: the main pipe continues straight through it (two
collinear runs) and the branch meets it at the corner angle. The pipe interior is the union
of the solid cylinders; its boundary is what the camera sees (see raycast.py).

Pieces that meet at a kinked joint are extended a little past the joint (`extend_*`) so that
the union has no wedge-shaped gap there; ground truth (network.yaml) keeps the nominal ends.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipemap.errors import PipemapError
from pipemap.network import Junction, PipeNetwork, Segment

_JOINT_MARGIN_M = 1e-3  # overlap beyond the geometric minimum at kinked joints


@dataclass(frozen=True)
class Pipe:
    """One straight piece: a solid cylinder around start -> end (plus the overlaps at joints)."""

    id: str
    start: np.ndarray
    end: np.ndarray
    closed_start: bool = False
    closed_end: bool = False
    extend_start: float = 0.0
    extend_end: float = 0.0

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    @property
    def axis(self) -> np.ndarray:
        return (self.end - self.start) / self.length

    @property
    def frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(e1, e2): unit vectors across the axis; phi = 0 at e1 (the wall's top for a
        horizontal pipe), increasing towards e2 = e1 x axis, so that (h, s = r * phi) is a
        right-handed chart seen from inside: wall markings read unmirrored from the pipe."""
        u = self.axis
        ref = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = ref - ref.dot(u) * u
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(e1, u)


@dataclass(frozen=True)
class PipeScene:
    """Everything the renderer and the ground truth need about a network."""

    radius: float
    pipes: tuple[Pipe, ...]
    junctions: tuple[Junction, ...] = ()
    runs: dict = field(default_factory=dict)  # run id -> (M, 3) axis polyline (joint vertices)

    def __post_init__(self):
        if not self.radius > 0:
            raise PipemapError(f"pipe radius must be positive, got {self.radius}", key="pipe.radius_m")
        for p in self.pipes:
            if not p.length > 0:
                raise PipemapError(f"pipe piece {p.id} has zero length")

    def pipe_index(self, pid: str) -> int:
        for i, p in enumerate(self.pipes):
            if p.id == pid:
                return i
        raise KeyError(pid)

    def network(self, visits=()) -> PipeNetwork:
        """Ground truth for network.yaml: every piece's nominal axis, the junction centroids."""
        segs = tuple(Segment(p.id, p.start.copy(), p.end.copy()) for p in self.pipes)
        return PipeNetwork(float(self.radius), segs, self.junctions, tuple(visits))

    def contains(self, points: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Whether points (..., 3) lie inside the union of the solid cylinders (by `tol` metres)."""
        pts = np.asarray(points, float)
        inside = np.zeros(pts.shape[:-1], bool)
        for p in self.pipes:
            q = pts - p.start
            h = q @ p.axis
            rad = np.linalg.norm(q - h[..., None] * p.axis, axis=-1)
            inside |= (h >= -p.extend_start) & (h <= p.length + p.extend_end) & (rad < self.radius - tol)
        return inside

    def axis_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (...) of points to the nearest piece axis (clamped to the piece)."""
        pts = np.asarray(points, float)
        best = np.full(pts.shape[:-1], np.inf)
        for p in self.pipes:
            q = pts - p.start
            h = np.clip(q @ p.axis, 0.0, p.length)
            best = np.minimum(best, np.linalg.norm(q - h[..., None] * p.axis, axis=-1))
        return best


# -- building networks ------------------------------------------------------------------------


def run_vertices(start, end, piece_length: float, sag_m: float = 0.0, misalign_m: float = 0.0,
                 rng: np.random.Generator | None = None) -> np.ndarray:
    """Joint vertices of a straight run built of pieces of about `piece_length`.

    The two end vertices stay exact (they are junction centroids or pipe ends); interior joints
    drop by a parabolic sag (deepest mid-run, world z down) and move by random misalignment
    (metres, standard deviation, across the axis).
    """
    a, b = np.asarray(start, float), np.asarray(end, float)
    n = max(1, int(round(np.linalg.norm(b - a) / piece_length)))
    f = np.linspace(0.0, 1.0, n + 1)
    v = a + f[:, None] * (b - a)
    if n > 1 and (sag_m or misalign_m):
        u = (b - a) / np.linalg.norm(b - a)
        down = np.array([0.0, 0.0, -1.0])
        down = down - down.dot(u) * u
        if np.linalg.norm(down) < 1e-9:
            down = np.cross(u, [1.0, 0.0, 0.0])
        down /= np.linalg.norm(down)
        side = np.cross(u, down)
        v[1:-1] += (4 * sag_m * f[1:-1] * (1 - f[1:-1]))[:, None] * down
        if misalign_m and rng is not None:
            off = rng.normal(0.0, misalign_m, (n - 1, 2))
            v[1:-1] += off[:, :1] * down + off[:, 1:] * side
    return v


def run_pipes(run_id: str, vertices: np.ndarray, radius: float, closed_start: bool, closed_end: bool) -> list[Pipe]:
    """Pieces along a vertex chain; kinked joints overlap by r * tan(kink) + a margin."""
    v = np.asarray(vertices, float)
    n = len(v) - 1
    ext = np.zeros(n + 1)
    for k in range(1, n):
        d0 = (v[k] - v[k - 1]) / np.linalg.norm(v[k] - v[k - 1])
        d1 = (v[k + 1] - v[k]) / np.linalg.norm(v[k + 1] - v[k])
        kink = np.arccos(np.clip(d0 @ d1, -1.0, 1.0))
        if kink > 1e-12:
            ext[k] = radius * np.tan(min(kink, 1.0)) + _JOINT_MARGIN_M
    pipes = []
    for k in range(n):
        pid = run_id if n == 1 else f"{run_id}.{k + 1}"
        pipes.append(Pipe(pid, v[k].copy(), v[k + 1].copy(),
                          closed_start=closed_start and k == 0, closed_end=closed_end and k == n - 1,
                          extend_start=float(ext[k]), extend_end=float(ext[k + 1])))
    return pipes


def straight_scene(length: float, radius: float, *, piece_length: float | None = None, sag_m: float = 0.0,
                   misalign_m: float = 0.0, seed: int = 0) -> PipeScene:
    """One straight pipe along world +x from the origin, axis at z = 0, both ends closed."""
    if not length > 0:
        raise PipemapError(f"pipe length must be positive, got {length}")
    rng = np.random.default_rng(seed)
    v = run_vertices([0, 0, 0], [length, 0, 0], piece_length or length, sag_m, misalign_m, rng)
    return PipeScene(float(radius), tuple(run_pipes("S1", v, radius, True, True)), (), {"S1": v})


def tee_loop_scene(corners: np.ndarray, radius: float, *, stub_length: float, piece_length: float = 3.0,
                   sag_m: float = 0.0, misalign_m: float = 0.0, seed: int = 0, main_out=()) -> PipeScene:
    """A closed loop through tees T1..Tn at `corners` (n, 3), in that order.

    Side k (run "S{k}") joins T{k} to T{k+1}. At each tee the incoming side continues straight
    as the main pipe into a closed stub (run "B{k}", `stub_length` beyond the centroid) and the
    outgoing side is the branch; at the tees numbered in `main_out` (1-based) it is the other way
    round: the outgoing side is the main pipe, its stub points back against it, and the incoming
    side arrives along the branch. Joints inside a side sag and are misaligned; the pieces next to
    a tee stay exactly on the nominal axes so that the axes meet at the centroid.
    """
    c = np.asarray(corners, float)
    n = len(c)
    flipped = {int(k) for k in main_out}
    if not flipped <= set(range(1, n + 1)):
        raise PipemapError(f"main_out names tees {sorted(flipped)}, the loop has T1..T{n}")
    rng = np.random.default_rng(seed)
    pipes: list[Pipe] = []
    runs: dict[str, np.ndarray] = {}
    for k in range(n):
        a, b = c[k], c[(k + 1) % n]
        v = run_vertices(a, b, piece_length, sag_m, misalign_m, rng)
        runs[f"S{k + 1}"] = v
        pipes += run_pipes(f"S{k + 1}", v, radius, False, False)
    for k in range(n):
        # the stub continues the main pipe's piece at the tee exactly, so the main pipe is one
        # straight cylinder through the tee (no wedge between the two)
        here = c[k]
        if k + 1 in flipped:
            outgoing = runs[f"S{k + 1}"]
            u = (outgoing[0] - outgoing[1]) / np.linalg.norm(outgoing[0] - outgoing[1])
        else:
            incoming = runs[f"S{(k - 1) % n + 1}"]
            u = (incoming[-1] - incoming[-2]) / np.linalg.norm(incoming[-1] - incoming[-2])
        v = np.stack([here, here + stub_length * u])
        runs[f"B{k + 1}"] = v
        pipes += run_pipes(f"B{k + 1}", v, radius, False, True)
    junctions = tuple(Junction(f"T{k + 1}", "tee", c[k].copy()) for k in range(n))
    return PipeScene(float(radius), tuple(pipes), junctions, runs)


def route_polyline(scene: PipeScene, legs: list[tuple[str, bool]]) -> np.ndarray:
    """Axis polyline following runs in order; (run id, reversed). Consecutive runs must share
    an end vertex (a junction centroid)."""
    pts: list[np.ndarray] = []
    for rid, rev in legs:
        v = scene.runs[rid][::-1] if rev else scene.runs[rid]
        if pts and np.linalg.norm(pts[-1] - v[0]) > 1e-9:
            raise ValueError(f"run {rid} does not continue the route")
        pts.extend(v[1:] if pts else v)
    return np.array(pts)
