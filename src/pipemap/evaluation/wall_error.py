"""How far the appearance map (appearance.ply) lies from the true pipe wall.

Issue 8 accepts the map when its points lie within 2 mm of the true wall on demo-loop. Two
figures answer it, both as distances to the wall of the true network (ground_truth/network.yaml):

- **global**: every point brought into the ground-truth frame by the rigid alignment the ATE
  uses (associated keyframe positions, `metrics.ate(..., with_scale=False).alignment`); on a
  straight run, whose positions leave the rotation about their line free, by all its keyframes'
  centres and orientations as a section's below. Drift accumulated along the run shows here as
  wall error, though the map may be right locally.
- **local**: each wall piece S<k> of run.json "wall_pieces" brought in by an alignment of its own
  straight section k's keyframes only (run.json "straight_sections"). This says whether the map
  is right where it was built, whatever the drift before it. An elbow's wall piece (kind `arc`)
  is brought in by the keyframes of its junction pass (run.json "junction_passes"), those that
  see it. A straight section's camera centres are nearly collinear, so positions alone leave
  the rotation about their line free, and the camera rides off the pipe axis,
  so that free rotation would move the pipe axis. The section
  alignment therefore also matches each keyframe's orientation: besides the camera centre c it
  pairs the three points c + r * R_wc[:, i] (r the pipe radius, so an orientation error weighs
  as much as the wall shift it causes at the wall) and solves one rigid Umeyama problem. The
  estimated orientations' own errors therefore enter the local figure, weighted by that lever.

A point is assigned to the piece whose axis (clamped to its ends; an elbow's arc) is nearest, in the
result's own frame, before any alignment.

Every segment's whole cylinder counts as wall, also where a branch's cylinder crosses the
through pipe at a tee (the opening, where no wall is). A point there would read nearer the wall
than it is; the appearance map leaves out points inside another piece, so few if any lie there.

Reads result files and ground truth only; never imports the estimators that produced them.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyParseError

from pipemap.errors import PipemapError
from pipemap.evaluation.align import Alignment, umeyama
from pipemap.evaluation.metrics import ASSOCIATION_TOLERANCE_S, associate
from pipemap.network import PipeNetwork
from pipemap.trajectory import Trajectory

WALL_TOLERANCE_M = 0.002  # issue 8's acceptance: within 2 mm of the true wall
# Pieces that meet at a kinked joint overlap slightly past their nominal ends (network.yaml keeps the
# nominal ends), so a wall point near a joint may lie just beyond both segments.
END_TOLERANCE_M = 0.005
CHUNK_POINTS = 250_000  # bounds the (chunk, segments) temporaries for maps of millions of points
NEAR_M = 0.05  # wall_distance measures a chunk against the segments within this of its bounding box first


@dataclass(frozen=True)
class WallStats:
    """Distances of map points to the true wall, in millimetres."""

    points: int
    median_mm: float
    p90_mm: float
    p95_mm: float
    max_mm: float
    within_2mm_pct: float

    @classmethod
    def of(cls, distances_m: np.ndarray) -> "WallStats":
        d = np.asarray(distances_m, float).ravel()
        if len(d) == 0:
            return cls(0, np.nan, np.nan, np.nan, np.nan, np.nan)
        median, p90, p95 = np.percentile(d, [50.0, 90.0, 95.0])
        within = 100.0 * np.count_nonzero(d <= WALL_TOLERANCE_M) / len(d)
        return cls(len(d), 1000.0 * float(median), 1000.0 * float(p90), 1000.0 * float(p95), 1000.0 * float(d.max()),
                   float(within))

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class PieceWall:
    """One wall piece after its own section's alignment."""

    piece: str
    section: int
    keyframes: int  # associated keyframes of the section used to align it
    stats: WallStats

    def as_dict(self) -> dict:
        return {"piece": self.piece, "section": self.section, "keyframes": self.keyframes, **self.stats.as_dict()}


@dataclass(frozen=True)
class AppearanceWall:
    """The appearance map against the true wall: globally aligned, and piece by piece."""

    global_: WallStats
    local: WallStats | None  # pooled over `pieces`; None when run.json gives no usable pieces
    pieces: tuple[PieceWall, ...] = ()
    notes: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        return {
            "threshold_mm": 1000.0 * WALL_TOLERANCE_M,
            "global": self.global_.as_dict(),
            "local": None if self.local is None else self.local.as_dict(),
            "pieces": [p.as_dict() for p in self.pieces],
        }


# -- distance to the true wall ----------------------------------------------------------------


def wall_distance(points: np.ndarray, network: PipeNetwork, end_tolerance_m: float = END_TOLERANCE_M) -> np.ndarray:
    """(N,) distance in metres from each of (N, 3) points to the nearest true pipe wall.

    Each segment's wall is an open tube of radius `network.radius_m` around start -> end,
    lengthened by `end_tolerance_m` at both ends. Within that axial extent a point's distance to
    it is |radial distance - r|; beyond it, the Euclidean distance to the tube's end rim. An arc's
    (an elbow's) wall is the torus around it: |distance to the axis circle - r| within its angle,
    chainage beyond its ends counting as for a straight tube. The result is the minimum over segments."""
    if not network.segments:
        raise ValueError("the network has no segments")
    lines = [s for s in network.segments if not s.is_arc]
    arcs = [s for s in network.segments if s.is_arc]
    p = np.asarray(points).reshape(-1, 3)
    out = np.full(len(p), np.inf)
    if lines:
        starts = np.array([s.start for s in lines])
        ends = np.array([s.end for s in lines])
        axes = np.array([s.axis for s in lines])
        lengths = np.array([s.length for s in lines])
        # A segment's wall lies inside its axis's bounding box widened by the radius and the end tolerance: a point
        # farther than NEAR_M from that box is farther than NEAR_M from the wall. Each chunk is first measured
        # against the segments near its own box only (a long network has hundreds); points found farther than
        # NEAR_M from all of those are measured again against every segment, so the result is exact.
        reach = network.radius_m + end_tolerance_m
        box_lo, box_hi = np.minimum(starts, ends) - reach, np.maximum(starts, ends) + reach
        for lo in range(0, len(p), CHUNK_POINTS):
            chunk = p[lo:lo + CHUNK_POINTS]
            near = np.all((box_lo <= chunk.max(axis=0) + NEAR_M) & (box_hi >= chunk.min(axis=0) - NEAR_M), axis=1)
            d = _line_distance(chunk, starts[near], axes[near], lengths[near], network.radius_m, end_tolerance_m)
            far = d > NEAR_M
            if far.any():
                d[far] = _line_distance(chunk[far], starts, axes, lengths, network.radius_m, end_tolerance_m)
            out[lo:lo + len(chunk)] = d
    for s in arcs:
        q = p - s.centre
        e1 = (s.start - s.centre) / s.bend_radius
        x, y, z = q @ e1, q @ np.cross(s.normal, e1), q @ s.normal
        theta = np.arctan2(y, x)
        off = np.hypot(np.hypot(x, y) - s.bend_radius, z) - network.radius_m
        beyond = np.maximum(s.bend_radius * np.maximum(-theta, theta - s.angle) - end_tolerance_m, 0.0)
        out = np.minimum(out, np.sqrt(off * off + beyond * beyond))
    return out


def _line_distance(points, starts, axes, lengths, radius: float, end_tolerance_m: float) -> np.ndarray:
    """(n,) distance of points to the nearest of the straight tubes (wall_distance); inf with no tube."""
    if not len(starts):
        return np.full(len(points), np.inf)
    h, q2 = _axial_and_square(points, starts, axes)
    off = np.sqrt(np.maximum(q2 - h * h, 0.0)) - radius
    beyond = np.maximum(np.maximum(-h, h - lengths) - end_tolerance_m, 0.0)
    return np.sqrt(np.min(off * off + beyond * beyond, axis=1))


def _axial_and_square(points: np.ndarray, starts: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, S) axial coordinate of each point along each unit axis from its start, and the squared
    distance to the start, from dot products rather than an (n, S, 3) array of differences.
    einsum, not `@`: a threaded BLAS is many times slower on these thin products when the cores
    are busy."""
    p = np.asarray(points, float)
    h = np.einsum("ik,jk->ij", p, axes) - np.einsum("ij,ij->i", starts, axes)
    q2 = np.einsum("ij,ij->i", p, p)[:, None] - 2.0 * np.einsum("ik,jk->ij", p, starts) \
        + np.einsum("ij,ij->i", starts, starts)
    return h, q2


# -- reading the result -----------------------------------------------------------------------


def read_appearance_points(path: str | Path) -> np.ndarray:
    """(N, 3) float32 x y z of appearance.ply's vertices; PipemapError naming the file if unreadable."""
    path = Path(path)
    try:
        ply = PlyData.read(str(path))
        vertex = ply["vertex"].data
        xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(np.float32, copy=False)
    except FileNotFoundError:
        raise PipemapError("not found", path) from None
    except OSError as exc:
        raise PipemapError(f"cannot read: {exc.strerror or exc}", path) from None
    except PlyParseError as exc:
        raise PipemapError(f"not a readable PLY file: {exc}", path) from None
    except (KeyError, ValueError) as exc:
        raise PipemapError(f"expected a vertex element with x y z: {exc}", path) from None
    if not np.all(np.isfinite(xyz)):
        raise PipemapError("vertices with non-finite coordinates", path)
    return xyz


@dataclass(frozen=True)
class _Piece:
    name: str
    section: int  # the straight section S<k> (-1: none)
    start: np.ndarray
    end: np.ndarray
    arc: tuple | None = None  # an elbow's (centre, unit normal, bend radius, angle rad): its axis turns from start
    keyframes: tuple[int, int] | None = None  # an elbow's junction pass: the keyframes that align it

    def axis_distance2(self, points: np.ndarray) -> np.ndarray:
        """(n,) squared distance of points to the axis, clamped to its ends (an elbow: to its arc)."""
        if self.arc is None:
            h, q2 = _axial_and_square(points, self.start[None], ((self.end - self.start) / self.length)[None])
            f = np.clip(h[:, 0], 0.0, self.length)
            return q2[:, 0] - 2.0 * f * h[:, 0] + f * f
        centre, normal, rho, angle = self.arc
        e1 = (self.start - centre) / rho
        q = np.asarray(points, float) - centre
        x, y, z = q @ e1, q @ np.cross(normal, e1), q @ normal
        a = np.arctan2(y, x)
        a = np.clip(np.where(a < -0.5 * (2 * np.pi - angle), a + 2 * np.pi, a), 0.0, angle)
        return (x - rho * np.cos(a)) ** 2 + (y - rho * np.sin(a)) ** 2 + z * z

    @property
    def length(self) -> float:
        return max(float(np.linalg.norm(self.end - self.start)), 1e-12)


def read_wall_pieces(run_json: Path) -> tuple[list[_Piece], dict[int, tuple[int, int]], str | None]:
    """run.json's wall pieces (straight, and elbows with the keyframes of their junction pass) and the keyframe
    range of each straight section, or a note."""
    try:
        run = json.loads(run_json.read_text())
    except FileNotFoundError:
        return [], {}, "no run.json: the local appearance-wall figure is skipped"
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return [], {}, f"run.json unreadable ({exc}): the local appearance-wall figure is skipped"
    items = run.get("wall_pieces") if isinstance(run, dict) else None
    if not isinstance(items, list) or not items:
        return [], {}, "run.json lists no wall_pieces: the local appearance-wall figure is skipped"
    sections = {}
    for s in run.get("straight_sections") or []:
        try:
            sections[int(s["section"])] = (int(s["first_keyframe"]), int(s["last_keyframe"]))
        except (KeyError, TypeError, ValueError):
            continue
    passes = {}
    for j in run.get("junction_passes") or []:
        try:
            passes.setdefault(str(j["id"]), (int(j["first_keyframe"]), int(j["last_keyframe"])))
        except (KeyError, TypeError, ValueError):
            continue
    pieces = [p for p in (_piece(item, passes) for item in items) if p is not None]
    if not pieces:
        return [], {}, "run.json's wall_pieces have no valid start and end: the local appearance-wall figure is skipped"
    return pieces, sections, None


def _piece(item, passes: dict[str, tuple[int, int]]) -> _Piece | None:
    try:
        name = str(item["name"])
        section = int(name[1:]) if name[:1] == "S" and name[1:].isdigit() else -1
        start, end = np.asarray(item["start"], float), np.asarray(item["end"], float)
        arc = None
        if item.get("kind") == "arc":
            centre, normal = np.asarray(item["centre"], float), np.asarray(item["normal"], float)
            arc = (centre, normal / np.linalg.norm(normal), float(np.linalg.norm(start - centre)),
                   float(np.radians(float(item["angle_deg"]))))
    except (KeyError, TypeError, ValueError, AttributeError):
        return None
    vectors = [start, end] + ([arc[0], arc[1]] if arc else [])
    if not all(v.shape == (3,) and np.all(np.isfinite(v)) for v in vectors):
        return None
    return _Piece(name, section, start, end, arc, passes.get(name) if arc else None)


# -- alignments -------------------------------------------------------------------------------


def section_alignment(est: Trajectory, gt: Trajectory, lever_m: float) -> tuple[Alignment, int] | None:
    """Rigid alignment of the keyframes `est` onto the ground truth by camera centres and
    orientations (see the module docstring); with the count of associated keyframes, or None
    with fewer than two."""
    ei, gi = associate(est.timestamps, gt.timestamps, ASSOCIATION_TOLERANCE_S)
    if len(ei) < 2:
        return None
    return umeyama(_pose_points(est.subset(ei), lever_m), _pose_points(gt.subset(gi), lever_m)), len(ei)


def _collinear(positions: np.ndarray, ratio: float = 0.01) -> bool:
    """Whether camera centres (N, 3) lie along one line: their second principal spread under `ratio` of the
    first. The ATE's alignment by positions then turns the run about that line at random, and with the camera
    off the pipe's axis the whole map with it (a straight pipe driven in and out: 20 % of its points within 2 mm
    globally, 99 % piece by piece); the global figure then takes the orientations too, as a section's does."""
    p = np.asarray(positions, float).reshape(-1, 3)
    if len(p) < 3:
        return True
    s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return bool(s[1] < ratio * s[0])


def _pose_points(traj: Trajectory, lever_m: float) -> np.ndarray:
    """Each camera centre and the tips of its three axes at `lever_m`: (4 N, 3)."""
    tips = traj.positions[:, None, :] + lever_m * np.swapaxes(traj.rotations, 1, 2)
    return np.concatenate([traj.positions[:, None, :], tips], axis=1).reshape(-1, 3)


def nearest_piece(points: np.ndarray, pieces: list[_Piece]) -> np.ndarray:
    """(N,) index of the piece whose axis (segment, or an elbow's arc) is nearest each point."""
    p = np.asarray(points, float).reshape(-1, 3)
    out = np.empty(len(p), dtype=np.int64)
    for lo in range(0, len(p), CHUNK_POINTS):
        chunk = p[lo:lo + CHUNK_POINTS]
        out[lo:lo + len(chunk)] = np.argmin(np.stack([x.axis_distance2(chunk) for x in pieces], axis=1), axis=1)
    return out


# -- the figure -------------------------------------------------------------------------------


def appearance_wall(result_dir: str | Path, network: PipeNetwork, est: Trajectory, gt: Trajectory,
                    alignment: Alignment) -> AppearanceWall:
    """The appearance map of `result_dir` against the true wall of `network`: globally under
    `alignment` (the ATE's estimate -> ground truth), and locally piece by piece (module
    docstring). `est` is the whole trajectory.tum (rows are keyframe numbers), `gt` the ground
    truth. PipemapError if appearance.ply is missing or unreadable."""
    result_dir = Path(result_dir)
    points = read_appearance_points(result_dir / "appearance.ply")
    if _collinear(est.positions):  # a straight run: the positions leave the roll about their line free
        held = section_alignment(est, gt, network.radius_m)
        alignment = alignment if held is None else held[0]
    global_ = WallStats.of(wall_distance(_moved(points, alignment), network))
    pieces, sections, note = read_wall_pieces(result_dir / "run.json")
    if note is not None:
        return AppearanceWall(global_, None, (), (note,))
    rows, pooled, skipped = _piece_errors(points, pieces, sections, network, est, gt)
    notes = ()
    if skipped:
        notes = (f"wall pieces {', '.join(skipped)} have no straight section (an elbow: junction pass) with 2 "
                 "keyframes in common with ground truth: left out of the local appearance-wall figure",)
    local = WallStats.of(np.concatenate(pooled)) if rows else None
    return AppearanceWall(global_, local, tuple(rows), notes)


def _piece_errors(points, pieces, sections, network, est, gt) -> tuple[list[PieceWall], list[np.ndarray], list[str]]:
    """Per piece: its points' distances under its own section's alignment; the pieces left out."""
    rows, pooled, skipped = [], [], []
    owner = nearest_piece(points, pieces)
    for i, piece in enumerate(pieces):
        aligned = piece_alignment(piece, sections, est, gt, network.radius_m)
        if aligned is None:
            skipped.append(piece.name)
            continue
        d = wall_distance(_moved(points[owner == i], aligned[0]), network)
        pooled.append(d)
        rows.append(PieceWall(piece.name, piece.section, aligned[1], WallStats.of(d)))
    return rows, pooled, skipped


def _moved(points: np.ndarray, alignment: Alignment) -> np.ndarray:
    """Alignment.apply through einsum (see _axial_and_square for why not `@`)."""
    R, t, s = alignment
    return s * np.einsum("ij,nj->ni", R, np.asarray(points, float)) + t


def piece_alignment(piece: _Piece, sections: dict[int, tuple[int, int]], est: Trajectory, gt: Trajectory,
                     lever_m: float) -> tuple[Alignment, int] | None:
    span = piece.keyframes if piece.arc is not None else sections.get(piece.section)
    if span is None:
        return None
    a, b = span
    if not 0 <= a <= b < len(est):
        return None
    return section_alignment(est.subset(np.arange(a, b + 1)), gt, lever_m)


__all__ = ["AppearanceWall", "PieceWall", "WallStats", "appearance_wall", "nearest_piece", "piece_alignment",
           "read_appearance_points", "read_wall_pieces",
           "section_alignment", "wall_distance", "WALL_TOLERANCE_M", "END_TOLERANCE_M"]
