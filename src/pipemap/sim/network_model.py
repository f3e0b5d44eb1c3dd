"""Pipe networks as the renderer sees them: straight cylinders (pieces) and bends of one internal radius.

A *run* is a chain of pieces between two junctions or ends (one straight pipe, possibly built
of several pieces that sag and are slightly misaligned at their joints). A tee is three runs
whose axes meet at the junction centroid: the main pipe continues straight through it (two
collinear runs) and the branch meets it at the corner angle. The pipe interior is the union
of the solid cylinders; its boundary is what the camera sees (see raycast.py).

Pieces that meet at a kinked joint are extended a little past the joint (`extend_*`) so that
the union has no wedge-shaped gap there; ground truth (network.yaml) keeps the nominal ends.

An elbow is a `Bend`: the solid torus piece around a circular arc of its bend radius, joined
tangentially to the straight pieces either side (bent_run). A cross is two straight pipes whose
axes cross at its centroid, built like a tee. The pieces of one run through elbows share one wall
texture (`chain`), laid out by chainage along the run, so the wall runs on unbroken into a bend.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipemap.errors import PipemapError
from pipemap.network import Junction, PipeNetwork, Segment
from pipemap.sim.wall_shape import WallShape

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
    up: np.ndarray | None = None  # phi = 0 direction across the axis (None: the world's up, see frame)
    chain: tuple | None = None  # (texture key, chainage of `start` along the chain, chain length): shared wall
    shape: WallShape | None = None  # an oval or dented cross-section (None: round)

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
        ref = _default_up(u) if self.up is None else np.asarray(self.up, float)
        e1 = ref - ref.dot(u) * u
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(e1, u)


def _default_up(u: np.ndarray) -> np.ndarray:
    return np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])


def _rotate(v: np.ndarray, n: np.ndarray, angle: float) -> np.ndarray:
    """v turned by `angle` about the unit axis n (Rodrigues)."""
    c, s = np.cos(angle), np.sin(angle)
    return v * c + np.cross(n, v) * s + n * (n @ v) * (1 - c)


@dataclass(frozen=True)
class Bend:
    """An elbow's bent pipe: the solid torus piece around the arc of `bend_radius` about `centre`, from
    `start` = centre + bend_radius * e1, turning anticlockwise about `normal` by `angle` (radians).

    Its own frame (e1, e2 = normal x e1, normal) puts the arc in the xy plane from +x towards +y. Wall
    coordinates: h = bend_radius * theta (chainage along the arc from start), phi around the tube from
    `up` carried along the arc (parallel transport: turned about the normal with the tangent)."""

    id: str
    centre: np.ndarray
    e1: np.ndarray
    normal: np.ndarray
    bend_radius: float
    angle: float
    up: np.ndarray  # phi = 0 at the start, across the start tangent
    junction: str | None = None
    chain: tuple | None = None

    @property
    def e2(self) -> np.ndarray:
        return np.cross(self.normal, self.e1)

    @property
    def basis(self) -> np.ndarray:
        """(3, 3) rows e1, e2, normal: world vectors -> the bend's frame."""
        return np.stack([self.e1, self.e2, self.normal])

    @property
    def length(self) -> float:
        return self.bend_radius * self.angle

    def axis_point(self, theta) -> np.ndarray:
        theta = np.asarray(theta, float)[..., None]
        return self.centre + self.bend_radius * (np.cos(theta) * self.e1 + np.sin(theta) * self.e2)

    @property
    def start(self) -> np.ndarray:
        return self.axis_point(0.0)

    @property
    def end(self) -> np.ndarray:
        return self.axis_point(self.angle)

    @property
    def end_tangent(self) -> np.ndarray:
        return -np.sin(self.angle) * self.e1 + np.cos(self.angle) * self.e2

    @property
    def end_up(self) -> np.ndarray:
        return _rotate(self.up, self.normal, self.angle)

    def local(self, points: np.ndarray) -> np.ndarray:
        """Points (..., 3) in the bend's frame (metres)."""
        return (np.asarray(points, float) - self.centre) @ self.basis.T

    def tube_coordinates(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(theta, distance to the axis circle) of world points (..., 3)."""
        q = self.local(points)
        return np.arctan2(q[..., 1], q[..., 0]), np.hypot(np.hypot(q[..., 0], q[..., 1]) - self.bend_radius, q[..., 2])

    def axis_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance of points to the arc (the axis circle clamped to the bend's angle)."""
        theta, d = self.tube_coordinates(points)
        ends = np.minimum(*(np.linalg.norm(np.asarray(points, float) - e, axis=-1) for e in (self.start, self.end)))
        return np.where((theta >= 0) & (theta <= self.angle), d, ends)


@dataclass(frozen=True)
class PipeScene:
    """Everything the renderer and the ground truth need about a network."""

    radius: float
    pipes: tuple[Pipe, ...]
    junctions: tuple[Junction, ...] = ()
    runs: dict = field(default_factory=dict)  # run id -> (M, 3) axis polyline (joint vertices)
    bends: tuple[Bend, ...] = ()  # pieces K.. of the union after the K straight ones

    def __post_init__(self):
        if not self.radius > 0:
            raise PipemapError(f"pipe radius must be positive, got {self.radius}", key="pipe.radius_m")
        for p in self.pipes:
            if not p.length > 0:
                raise PipemapError(f"pipe piece {p.id} has zero length")
        for b in self.bends:
            if not (b.bend_radius > self.radius and 0 < b.angle < np.pi):
                raise PipemapError(f"bend {b.id} needs a bend radius above the pipe radius, an angle in (0, 180) deg")

    @property
    def pieces(self) -> tuple:
        """Every piece of the union: the straight ones, then the bends (the renderer's piece indices)."""
        return self.pipes + self.bends

    def pipe_index(self, pid: str) -> int:
        for i, p in enumerate(self.pipes):
            if p.id == pid:
                return i
        raise KeyError(pid)

    def network(self, visits=()) -> PipeNetwork:
        """Ground truth for network.yaml: every piece's nominal axis, the junction centroids."""
        segs = [Segment(p.id, p.start.copy(), p.end.copy()) for p in self.pipes]
        segs += [Segment(b.id, b.start, b.end, b.centre.copy(), b.junction) for b in self.bends]
        return PipeNetwork(float(self.radius), tuple(segs), self.junctions, tuple(visits))

    def fillet_radii(self, vertices: np.ndarray) -> np.ndarray:
        """Per route vertex, the bend radius of the elbow whose vertex it is (NaN elsewhere): a route
        follows an elbow's arc."""
        out = np.full(len(vertices), np.nan)
        for j in self.junctions:
            if j.type == "elbow":
                out[np.linalg.norm(np.asarray(vertices) - j.centroid, axis=1) < 1e-9] = j.bend_radius_m
        return out

    def contains(self, points: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Whether points (..., 3) lie inside the union of the solid cylinders (by `tol` metres)."""
        pts = np.asarray(points, float)
        inside = np.zeros(pts.shape[:-1], bool)
        for p in self.pipes:
            q = pts - p.start
            h = q @ p.axis
            rad = np.linalg.norm(q - h[..., None] * p.axis, axis=-1)
            inside |= (h >= -p.extend_start) & (h <= p.length + p.extend_end) & (rad < self.radius - tol)
        for b in self.bends:
            theta, d = b.tube_coordinates(pts)
            inside |= (theta >= 0) & (theta <= b.angle) & (d < self.radius - tol)
        return inside

    def axis_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (...) of points to the nearest piece axis (clamped to the piece)."""
        pts = np.asarray(points, float)
        best = np.full(pts.shape[:-1], np.inf)
        for p in self.pipes:
            q = pts - p.start
            h = np.clip(q @ p.axis, 0.0, p.length)
            best = np.minimum(best, np.linalg.norm(q - h[..., None] * p.axis, axis=-1))
        for b in self.bends:
            best = np.minimum(best, b.axis_distance(pts))
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


def bent_run(run_id: str, vertices: np.ndarray, radius: float, elbows: dict, *, closed_start: bool = False,
             closed_end: bool = False) -> tuple[list[Pipe], list[Bend], list[Junction]]:
    """A run through elbows: straight pieces joined tangentially by bends.

    `elbows` maps an interior vertex index to (elbow id, bend radius): the run turns there on an arc
    whose tangent lines meet at the vertex (the elbow's centroid). An interior vertex without an
    elbow must be straight through (a tee's or cross's centroid on the run). All pieces share one
    wall texture (chain key `run_id`) laid out by chainage along the run, with phi = 0 carried along.
    """
    v = np.asarray(vertices, float)
    d = np.diff(v, axis=0)
    seg_len = np.linalg.norm(d, axis=1)
    dirs = d / seg_len[:, None]
    tang = np.zeros(len(v))
    for k in range(1, len(v) - 1):
        turn = float(np.arccos(np.clip(dirs[k - 1] @ dirs[k], -1.0, 1.0)))
        if k in elbows:
            if not 1e-6 < turn < np.pi - 1e-6:
                raise PipemapError(f"run {run_id}: elbow {elbows[k][0]} must turn by more than 0 and less than 180 deg")
            tang[k] = elbows[k][1] * np.tan(turn / 2)
        elif turn > 1e-9:
            raise PipemapError(f"run {run_id}: vertex {k} turns by {np.degrees(turn):.3f} deg but is no elbow")
    if np.any(tang[:-1] + tang[1:] > seg_len + 1e-12):
        raise PipemapError(f"run {run_id}: the elbows' arcs overlap (a straight piece is shorter than its bends need)")
    pipes: list[Pipe] = []
    bends: list[Bend] = []
    junctions: list[Junction] = []
    pieces: list[tuple] = []  # (kind, args, chainage length)
    up = _default_up(dirs[0])
    up = up - (up @ dirs[0]) * dirs[0]
    up /= np.linalg.norm(up)
    a = v[0]
    for k in range(1, len(v)):
        if k < len(v) - 1 and k not in elbows:
            continue  # straight through: the next piece goes on along the same line
        b = v[k] - tang[k] * dirs[k - 1]
        pieces.append(("line", (a.copy(), b.copy(), up.copy()), float(np.linalg.norm(b - a))))
        if k == len(v) - 1:
            break
        jid, rho = elbows[k]
        turn = float(np.arccos(np.clip(dirs[k - 1] @ dirs[k], -1.0, 1.0)))
        inward = dirs[k] - (dirs[k] @ dirs[k - 1]) * dirs[k - 1]
        inward /= np.linalg.norm(inward)
        centre = b + rho * inward
        e1 = -inward
        normal = np.cross(e1, dirs[k - 1])
        pieces.append(("bend", (jid, centre, e1, normal, float(rho), turn, up.copy()), rho * turn))
        junctions.append(Junction(jid, "elbow", v[k].copy(), float(np.degrees(turn)), float(rho)))
        up = _rotate(up, normal, turn)
        a = v[k] + tang[k] * dirs[k]
    total = float(sum(p[2] for p in pieces))
    h0 = 0.0
    for n, (kind, args, length) in enumerate(pieces):
        chain = (run_id, h0, total)
        if kind == "line":
            p0, p1, u = args
            pid = run_id if len(pieces) == 1 else f"{run_id}.{n // 2 + 1}"
            pipes.append(Pipe(pid, p0, p1, closed_start and n == 0, closed_end and n == len(pieces) - 1, up=u,
                              chain=chain))
        else:
            jid, centre, e1, normal, rho, turn, u = args
            bends.append(Bend(f"{jid}.arc", centre, e1, normal, rho, turn, u, jid, chain))
        h0 += length
    return pipes, bends, junctions


def network_scene(radius: float, runs: list[tuple], junctions: list[Junction] = ()) -> PipeScene:
    """A scene of runs through elbows (bent_run), each (run id, vertices, elbows, closed_start, closed_end),
    meeting at the tees and crosses `junctions` (their centroids are run ends or straight-through
    vertices); the elbows' junctions are added in run order."""
    pipes: list[Pipe] = []
    bends: list[Bend] = []
    found: list[Junction] = list(junctions)
    table: dict[str, np.ndarray] = {}
    for rid, vertices, elbows, closed_start, closed_end in runs:
        p, b, j = bent_run(rid, vertices, radius, elbows, closed_start=closed_start, closed_end=closed_end)
        pipes += p
        bends += b
        found += j
        table[rid] = np.asarray(vertices, float)
    return PipeScene(float(radius), tuple(pipes), tuple(found), table, tuple(bends))


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
