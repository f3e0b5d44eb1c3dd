"""The mapped pipe network: straight sections with their fitted cylinders, and the tees between them.

After the VO, each straight section gets cylinders of the pipe radius fitted to its scene points
(fisheye paper III-D): one to the whole section (its axis, for the unrolled wall image and the
appearance map, bent where the run sags: `pipemap.geometry.bend`) and one to each of its ends, the
points around the first / last `length_m` of camera path, relative to the first / last pose. Runs are
laid from pieces that kink a little at their joints, and the tee solve carries an end cylinder's tilt
into the next section's heading, so each end is also fitted over half that length, and the half is
taken where its direction differs from the whole's beyond the noise of both fits (a chi-square test
on their covariances): a joint kinks within the length. A junction section (frames classified as a
T-intersection) lies between two straight sections; its centre I is where the end cylinder
before it and the start cylinder after it meet (the two-cylinder model's intersection point, the
closest approach of the two axes). When the two axes are nearly parallel the robot went straight
through the tee and the axes do not fix I along the pipe: I is then the junction keyframes' mean
camera centre, projected onto the axis. Two junction sections with only a straight section too short
for a cylinder between them are one pass: the classification flickered there (a forward camera sees
the tee ahead, the far end round again for a few frames, then the tee), and each of the two halves
would have had a straight section on one side only, its centre left to the camera path.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipemap.frontend.tracks import Keyframe
from pipemap.geometry.bend import fit_bend
from pipemap.geometry.cylinder import Cylinder, CylinderFit, axis_frame, fit_cylinder, path_chord

STRAIGHT_THROUGH_DEG = 20.0  # axes closer to parallel than this cannot place a tee centre
KINK_CHI2 = 13.8  # chi-square, 2 degrees of freedom, p = 0.001: the end's two directions differ beyond noise
MAX_KINK_DEG = 3.0  # joints kink by less; a shorter fit that far off has failed (too few points, another pipe's)
# A whole section's straight cylinder is fitted to at most this many of its wall points (every n-th): they fix its
# four numbers to micrometres, and over a 64 m section's 480,000 each of its 200 iterations had taken 0.1 s. Its
# bent axis is fitted to them all.
WHOLE_FIT_POINTS = 100_000


@dataclass
class MappedSection:
    number: int  # the VO section number
    first: int  # keyframe numbers (inclusive)
    last: int
    cylinder: Cylinder | None  # fitted to the whole section
    start: Cylinder | None  # fitted to the first length_m, relative to the first pose
    end: Cylinder | None  # ... the last length_m, relative to the last pose
    start_h: float = 0.0  # axial extent of the section's camera centres on `cylinder` (camera_extent)
    end_h: float = 0.0
    start_length_m: float = 0.0  # camera path the start / end cylinder was fitted over (0: no cylinder)
    end_length_m: float = 0.0
    problems: list[str] = field(default_factory=list)
    # The bent axis of the whole section: knots (axial coordinates on `cylinder`) and the axis's
    # world offsets across it there (K, 3); None when straight.
    bend: tuple[np.ndarray, np.ndarray] | None = None

    def to_dict(self) -> dict:
        def cyl(c):
            return None if c is None else {"origin": c.origin.round(6).tolist(),
                                           "direction": c.direction.round(6).tolist(), "radius": c.radius}
        return {"section": self.number, "first_keyframe": self.first, "last_keyframe": self.last,
                "cylinder": cyl(self.cylinder), "start_cylinder": cyl(self.start), "end_cylinder": cyl(self.end),
                "start_length_m": self.start_length_m, "end_length_m": self.end_length_m,
                "bend": None if self.bend is None else {"h": self.bend[0].round(6).tolist(),
                                                         "offset": self.bend[1].round(7).tolist()},
                "problems": self.problems}


@dataclass
class MappedJunction:
    id: str
    centroid: np.ndarray  # (3,) world
    keyframe: int  # the keyframe nearest the centre
    first: int  # keyframe numbers of the junction section (inclusive)
    last: int
    before: int | None  # straight section numbers either side (None at either end of the run)
    after: int | None
    angle_deg: float  # between the two axes (nan when one side is missing)
    method: str  # "axes" | "straight-through" | "path" | "tee-model"
    gap_m: float = float("nan")  # closest-approach distance of the two axes
    through: str | None = None  # which side's pipe runs on through the tee ("red" = before, "blue" = after)
    type: str = "tee"  # "tee" | "cross" (a straight-through pass that found openings on both sides) | "elbow"
    opening: dict | None = None  # the side opening that placed a straight-through pass (SideOpening.to_dict)
    bend_radius_m: float = float("nan")  # an elbow's, where its bend's wall fixed it
    branch: np.ndarray | None = None  # world unit direction from the centre into the side branch (side opening)
    modelled: bool = False  # an elbow solved with its bend's wall (backend/join.py): angle and bend radius from it
    # An elbow solved with its bend: world unit directions (2, 3) of the pipe's axis into the vertex (the centroid)
    # and out of it, as the solve found them; its arc and wall piece are tangent to these, not to the sections' axes.
    axes: np.ndarray | None = None

    def to_dict(self) -> dict:
        d = {"id": self.id, "type": self.type, "centroid": [round(float(v), 6) for v in self.centroid],
             "keyframe": int(self.keyframe)}
        if self.type == "elbow":
            d["angle_deg"] = round(float(self.angle_deg), 4)
            if np.isfinite(self.bend_radius_m):
                d["bend_radius_m"] = round(float(self.bend_radius_m), 5)
        return d

    def pass_record(self) -> dict:
        """The pass as run.json `junction_passes` and the route builder read it: `to_dict` with its keyframes and,
        for an elbow solved with its bend, the solved axes."""
        d = dict(self.to_dict(), first_keyframe=self.first, last_keyframe=self.last)
        if self.type == "elbow" and self.axes is not None:
            d["axes"] = np.asarray(self.axes, float).round(7).tolist()
        return d


def section_points(keyframes: list[Keyframe], first: int, last: int, tids: np.ndarray) -> np.ndarray:
    """Positions in `tids` (sorted track ids with a 3D point) of the points seen by keyframes first..last."""
    seen = np.unique(np.concatenate([keyframes[k].track_ids for k in range(first, last + 1)]))
    pos = np.searchsorted(tids, seen)
    ok = pos < len(tids)
    ok[ok] = tids[pos[ok]] == seen[ok]
    return pos[ok]


def _fit(points: np.ndarray, centres: np.ndarray, R_ref, c_ref, radius: float, huber: float) -> CylinderFit | None:
    direction = path_chord(centres)
    if len(points) < 20 or np.linalg.norm(direction) < 2 * radius * 0.25:
        return None
    try:
        return fit_cylinder(points, radius, reference=(R_ref, c_ref), direction=direction, huber=huber)
    except (ValueError, np.linalg.LinAlgError):
        return None


def _end_fit(end: str, length: float, path: np.ndarray, sec, keyframes, tids_sorted, points_sorted, poses,
             radius: float, huber_m: float) -> CylinderFit | None:
    """The cylinder of the points along the section's first / last `length` of camera path (`path`: the
    distance travelled at each of its keyframes), relative to its first / last pose."""
    sel = path <= length if end == "start" else path >= path[-1] - length
    ks = np.flatnonzero(sel) + sec.first
    ref = sec.first if end == "start" else sec.last
    return stretch_cylinder(keyframes, poses, int(ks.min()), int(ks.max()), tids_sorted, points_sorted, radius,
                            huber_m, ref)


def stretch_cylinder(keyframes, poses: np.ndarray, k0: int, k1: int, tids_sorted: np.ndarray,
                     points_sorted: np.ndarray, radius: float, huber_m: float, ref: int | None = None
                     ) -> CylinderFit | None:
    """The known-radius cylinder of the map points (`points_sorted` by their track ids `tids_sorted`) seen by
    keyframes k0..k1 near their camera path, relative to keyframe `ref`'s pose (default k0)."""
    pos = section_points(keyframes, k0, k1, tids_sorted)
    P, C = points_sorted[pos], poses[k0:k1 + 1, :3, 3]
    ref = k0 if ref is None else ref
    return _fit(P[_near_path(P, C, 0.5 * radius)], C, poses[ref, :3, :3], poses[ref, :3, 3], radius, huber_m)


def _straight_end(full: CylinderFit | None, half: CylinderFit | None) -> tuple[CylinderFit | None, bool]:
    """The end cylinder over the whole fit length, or over its half nearest the tee where the two
    directions differ by more than the half's extra noise explains (the pipe kinks at a joint
    within the length); and whether the half was taken."""
    if full is None or half is None or full.covariance is None or half.covariance is None:
        return (half, True) if full is None else (full, False)
    delta = half.params[:2] - full.params[:2]  # both relative to the same end pose
    extra = half.covariance[:2, :2] - full.covariance[:2, :2]
    if np.linalg.eigvalsh(extra)[0] <= 0:
        extra = half.covariance[:2, :2]
    kinked = float(delta @ np.linalg.solve(extra, delta)) > KINK_CHI2 and np.degrees(np.abs(delta)).max() < MAX_KINK_DEG
    return (half, True) if kinked else (full, False)


def _fit_bend(cyl: Cylinder, points: np.ndarray, huber: float, knot_m: float, kink_rad: float,
              sigma_m: float, offset_sigma_m: float) -> tuple[np.ndarray, np.ndarray] | None:
    near = np.abs(cyl.distance(points)) < 4 * huber  # wall points, not the fit's outliers
    if near.sum() < 20:
        return None
    e1 = axis_frame(cyl.direction)[:, 0]
    e2 = np.cross(cyl.direction, e1)
    v = points[near] - cyl.origin
    h = v @ cyl.direction
    knots, o = fit_bend(h, np.column_stack([v @ e1, v @ e2]), cyl.radius, knot_m, kink_rad, huber, sigma_m,
                        offset_sigma_m)
    return knots.z, np.outer(o[:, 0], e1) + np.outer(o[:, 1], e2)


def _near_path(points: np.ndarray, centres: np.ndarray, margin: float) -> np.ndarray:
    """Points whose projection on the path's chord (`path_chord`) falls within the centres' (+- margin)."""
    d = path_chord(centres)
    L = np.linalg.norm(d)
    if L <= 0:
        return np.zeros(len(points), bool)
    along = (centres - centres[0]) @ (d / L)
    s = (points - centres[0]) @ (d / L)
    return (s > min(along.min(), 0.0) - margin) & (s < max(along.max(), L) + margin)


def map_sections(sections, keyframes: list[Keyframe], poses: np.ndarray, points: np.ndarray, tids: np.ndarray,
                 radius: float, length_m: float = 1.0, huber_m: float = 0.005,
                 bend: tuple[float, float, float, float] | None = None) -> list[MappedSection]:
    """Cylinders of every straight section (see the module docstring). `sections`: the VO's SectionReports.
    bend = (knot spacing m, kink sigma rad, point sigma m, offset sigma m): also fit each whole-section cylinder's
    bent axis (`pipemap.geometry.bend.fit_bend`)."""
    order = np.argsort(tids)
    tids_sorted, points_sorted = tids[order], points[order]
    centres = poses[:, :3, 3]
    out = []
    for sec in sections:
        if sec.kind != "straight":
            continue
        ms = MappedSection(sec.number, sec.first, sec.last, None, None, None)
        pos = section_points(keyframes, sec.first, sec.last, tids_sorted)
        P = points_sorted[pos]
        C = centres[sec.first:sec.last + 1]
        keep = _near_path(P, C, radius)
        stride = max(1, -(-int(keep.sum()) // WHOLE_FIT_POINTS))
        whole = _fit(P[keep][::stride], C, poses[sec.first, :3, :3], C[0], radius, huber_m)
        ms.cylinder = whole.cylinder if whole is not None else None
        if ms.cylinder is not None and bend is not None:
            ms.bend = _fit_bend(ms.cylinder, P[keep], huber_m, *bend)
        path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(C, axis=0), axis=1))])
        for end in ("start", "end"):
            fit, shortened = _straight_end(*(_end_fit(end, length, path, sec, keyframes, tids_sorted, points_sorted,
                                                      poses, radius, huber_m) for length in (length_m, 0.5 * length_m)))
            setattr(ms, end, None if fit is None else fit.cylinder)
            setattr(ms, f"{end}_length_m", 0.0 if fit is None else (0.5 if shortened else 1.0) * length_m)
        if ms.cylinder is not None:
            ms.start_h, ms.end_h = camera_extent(ms.cylinder.axial(C))
        else:
            ms.problems.append("too few points or too short for a cylinder fit")
        out.append(ms)
    return out


def camera_extent(h: np.ndarray) -> tuple[float, float]:
    """(start, end) of a section's pipe from its camera centres' axial coordinates `h` in order: from the first
    camera to the one farthest from it. A crawler that drives in and reverses out ends where it began; its
    section's wall still runs to where it turned back."""
    h = np.asarray(h, float)
    return float(h[0]), float(h[int(np.argmax(np.abs(h - h[0])))])


def axes_meeting_point(a: Cylinder, b: Cylinder) -> tuple[np.ndarray, float, float]:
    """Midpoint of the closest approach of two axes, their distance there, and the angle between them (deg)."""
    d1, d2 = a.direction, b.direction
    w = a.origin - b.origin
    b12 = d1 @ d2
    den = 1.0 - b12 * b12
    angle = float(np.degrees(np.arccos(np.clip(abs(b12), 0.0, 1.0))))
    if den < 1e-9:
        return 0.5 * (a.origin + b.origin), float(np.linalg.norm(w - (w @ d1) * d1)), angle
    s = (b12 * (w @ d2) - (w @ d1)) / den
    t = ((w @ d2) - b12 * (w @ d1)) / den
    p1, p2 = a.origin + s * d1, b.origin + t * d2
    return 0.5 * (p1 + p2), float(np.linalg.norm(p1 - p2)), angle


def map_junctions(sections, mapped: list[MappedSection], poses: np.ndarray) -> list[MappedJunction]:
    """Tee centres of every junction section, in the order the camera passes them (see the module docstring)."""
    by_number = {m.number: m for m in mapped}
    centres = poses[:, :3, 3]
    out: list[MappedJunction] = []
    i = -1
    while i + 1 < len(sections):
        i += 1
        sec = sections[i]
        if sec.kind != "junction":
            continue
        prev = sections[i - 1] if i > 0 and sec.linked else None
        first, last = sec.first, sec.last
        while _no_cylinder_between(sections, i, by_number):
            i += 2
            last = sections[i].last
        nxt = sections[i + 1] if i + 1 < len(sections) and sections[i + 1].linked else None
        before = by_number.get(prev.number) if prev is not None else None
        after = by_number.get(nxt.number) if nxt is not None else None
        a = before.end if before is not None else None
        b = after.start if after is not None else None
        path_centre = centres[first:last + 1].mean(axis=0)
        angle, gap = float("nan"), float("nan")
        if a is not None and b is not None:
            centroid, gap, angle = axes_meeting_point(a, b)
            method = "axes"
            if angle < STRAIGHT_THROUGH_DEG:
                centroid = a.origin + a.axial(path_centre) * a.direction
                method = "straight-through"
        elif a is not None or b is not None:
            c = a if a is not None else b
            centroid = c.origin + c.axial(path_centre) * c.direction
            method = "path"
        else:
            centroid, method = path_centre, "path"
        k = first + int(np.argmin(np.linalg.norm(centres[first:last + 1] - centroid, axis=1)))
        out.append(MappedJunction(f"T{len(out) + 1}", np.asarray(centroid, float), k, first, last,
                                  None if before is None else before.number, None if after is None else after.number,
                                  angle, method, gap))
    return out


def _no_cylinder_between(sections, i: int, by_number: dict) -> bool:
    """Whether junction section i is followed, with tracking unbroken, by a straight section that got no
    cylinder and then by another junction section: one pass (module docstring)."""
    if i + 2 >= len(sections):
        return False
    mid, nxt = sections[i + 1], sections[i + 2]
    m = by_number.get(mid.number)
    return (mid.kind == "straight" and nxt.kind == "junction" and mid.linked and nxt.linked
            and (m is None or m.cylinder is None))


__all__ = ["MappedSection", "MappedJunction", "map_sections", "map_junctions", "axes_meeting_point", "wall_pieces",
           "camera_extent",
           "section_points", "name_junctions", "stretch_cylinder",
           "STRAIGHT_THROUGH_DEG"]


def name_junctions(junctions: list[MappedJunction], radius: float, same_radii: float = 2.0) -> list[MappedJunction]:
    """Give every tee pass its tee's name: a pass whose centre lies within `same_radii` pipe radii of an
    earlier tee's is a revisit of it (after loop closure the two centres differ by the residual drift,
    far less than the spacing of distinct tees). Names follow first passage, by type: tees T1, T2, ...,
    crosses X1, ..., elbows E1, .... Returns one MappedJunction per distinct junction, in the order the
    camera first passes them, its centre the mean of its passes."""
    tees: list[list[MappedJunction]] = []
    for j in junctions:
        near = [t for t in tees if np.linalg.norm(t[0].centroid - j.centroid) < same_radii * radius]
        if near:
            near[0].append(j)
        else:
            tees.append([j])
    out = []
    counts: dict[str, int] = {}
    for passes in tees:
        kind = _kind(passes)
        counts[kind] = counts.get(kind, 0) + 1
        for j in passes:
            j.id = f"{_PREFIX[kind]}{counts[kind]}"
        first = passes[0]
        out.append(MappedJunction(first.id, np.mean([j.centroid for j in passes], axis=0), first.keyframe, first.first,
                                  first.last, first.before, first.after, first.angle_deg, first.method, first.gap_m,
                                  first.through, kind, first.opening, first.bend_radius_m, first.branch))
    return out


_PREFIX = {"tee": "T", "cross": "X", "elbow": "E"}


def _kind(passes: list[MappedJunction]) -> str:
    """A junction seen as a cross on any pass is a cross (a turning pass sees only one of its branches)."""
    return "cross" if any(j.type == "cross" for j in passes) else passes[0].type


def _tangent_length(j: MappedJunction) -> float:
    """How far before and after an elbow's vertex its bend takes over from the straight pipes (0 at a tee)."""
    if j.type != "elbow" or not np.isfinite(j.bend_radius_m):
        return 0.0
    return float(j.bend_radius_m * np.tan(np.radians(j.angle_deg) / 2))


def wall_pieces(mapped: list[MappedSection], junctions: list[MappedJunction], up) -> list[dict]:
    """The straight pieces of pipe wall the appearance map and unrolled images sample: each straight
    section's fitted cylinder, from its first camera (or the tee before it) to its last camera (or
    the tee after it). At a tee the pipe that runs on through it (`MappedJunction.through`, from
    the tee solve) is extended one radius past the centre I, to its far wall; the branch starts or
    ends at I, so that its cylinder cuts no false opening in the far wall. When the through pipe is
    unknown both end at I. At an elbow both end where its bend begins (its wall is the bend's, a torus that
    no straight piece samples). `up` is the world direction of 12 o'clock. Returned as the run.json
    "wall_pieces" records {name, start, end, radius, up, unroll}."""
    before = {j.after: j for j in junctions if j.after is not None}
    after = {j.before: j for j in junctions if j.before is not None}
    out = []
    for m in mapped:
        cyl = m.cylinder
        if cyl is None:
            continue
        h0, h1 = m.start_h, m.end_h
        sign = 1.0 if h1 >= h0 else -1.0
        if m.number in before:
            j = before[m.number]
            h0 = float(cyl.axial(j.centroid)) - (sign * cyl.radius if j.through == "blue" else 0.0) \
                + sign * _tangent_length(j)
        if m.number in after:
            j = after[m.number]
            h1 = float(cyl.axial(j.centroid)) + (sign * cyl.radius if j.through == "red" else 0.0) \
                - sign * _tangent_length(j)
        if abs(h1 - h0) < 2 * cyl.radius * 0.25:
            continue
        start = cyl.origin + h0 * cyl.direction
        end = cyl.origin + h1 * cyl.direction
        piece = {"name": f"S{m.number}", "start": start.round(6).tolist(), "end": end.round(6).tolist(),
                 "radius": cyl.radius, "up": [float(v) for v in up], "unroll": True}
        if m.bend is not None:
            h = sign * (m.bend[0] - h0)  # the knots as the piece's h, from its start
            order = np.argsort(h)
            piece["bend"] = {"h": h[order].round(6).tolist(), "offset": m.bend[1][order].round(7).tolist()}
        out.append(piece)
    return out
