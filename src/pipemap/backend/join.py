"""Join the straight sections through their tees with the two-cylinder model (fisheye paper III-D).

The VO chains the sections through each junction with relative poses alone. Here, tee by tee in
the order the camera passes them, the junction's keyframes, the points they see and the tee
parameters Phi are bundle-adjusted with both pipes' cylinders (`pipemap.backend.junction`): the
straight section before the tee (red) is held, with its last `bundle.tee_hold_keyframes`
keyframes; the straight section after it (blue) moves as one rigid body with Phi through its first
pose P_b and first `bundle.tee_attach_keyframes`. Everything the camera did after P_b then takes the
same rigid correction (`PipeMap.move_after`), so the next tee starts from the corrected place. The
tee centre is the model's intersection point I. A junction without a straight section on both
sides, whose end cylinders could not be fitted, or whose solve fails keeps the VO's chaining and its
axes-based centre, and says why.

An elbow is joined the same way with the wall of its bend left out of the cylinder term: its straight
pipes are the two cylinders up to where the bend begins, the points on the bend's arc (`elbow.on_arc`,
at the bend radius found so far) count by their reprojection only, and I is its vertex. With
`bundle.elbow_free_red_axis` (the default) the axis of the pipe before it is solved with the bend, from that pipe's
wall and the bend's as the solve sees them, rather than held at the end fit of a section whose heading the previous
elbow set. The straight sections keep their own cylinders; the elbow keeps the solved axes (`MappedJunction.axes`),
which its arc and wall piece follow, since the cameras through the bend were solved against them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.backend.bundle import Observations
from pipemap.backend.elbow import ARC_MARGIN_DEG, bend_of, model_bend, on_arc
from pipemap.backend.junction import solve_junction
from pipemap.backend.end_cylinders import fit_end_cylinder
from pipemap.backend.network_map import section_points
from pipemap.backend.pipe_map import PipeMap, moved_cylinder
from pipemap.camera.base import CameraModel
from pipemap.config import Settings
from pipemap.errors import PipemapError
from pipemap.frontend.tracks import Keyframe
from pipemap.geometry.cylinder import Cylinder


@dataclass
class JoinReport:
    junction: str
    status: str  # "tee-model" or why the VO chaining was kept
    keyframes: int = 0
    points: int = 0
    observations: int = 0
    rms_px: float = float("nan")
    cylinder_rms_m: float = float("nan")
    angle_deg: float = float("nan")
    correction_m: float = float("nan")  # how far the blue section's first pose moved
    correction_deg: float = float("nan")
    time_s: float = 0.0
    free_angle_deg: float = float("nan")  # the angle the solve found with it free
    angle_held: bool = False  # the solve held it near a tee's angle (bundle.tee_angles_deg)
    free_rms_px: float = float("nan")
    free_angle_off_deg: float = float("nan")  # a held solve's free angle from the tee angle it was held near

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else
                    (round(v, 6) if isinstance(v, float) else v)) for k, v in self.__dict__.items()}


def _observations(keyframes: list[Keyframe], active: list[np.ndarray], lo: int, hi: int, tids: np.ndarray):
    """Observations of points (sorted track ids `tids`) by keyframes lo..hi; points seen at least twice."""
    ks, pos, px = [], [], []
    for k in range(lo, hi + 1):
        kf = keyframes[k]
        p = np.searchsorted(tids, kf.track_ids)
        ok = p < len(tids)
        ok[ok] = tids[p[ok]] == kf.track_ids[ok]
        ok &= active[k]
        ks.append(np.full(int(ok.sum()), k - lo))
        pos.append(p[ok])
        px.append(kf.keypoints[ok])
    ks, pos, px = np.concatenate(ks), np.concatenate(pos), np.concatenate(px)
    uniq, inv, counts = np.unique(pos, return_inverse=True, return_counts=True)
    keep = counts[inv] >= 2
    uniq, inv = np.unique(pos[keep], return_inverse=True)
    return uniq, Observations(ks[keep], inv, px[keep])


def join_sections(pipe_map: PipeMap, active: list[np.ndarray], camera: CameraModel, radius: float,
                  settings: Settings, exact_angles: bool = False) -> tuple[PipeMap, list[JoinReport]]:
    """The map with every tee the model could solve joined (its centre the model's I), and a report per
    junction. `active`: per keyframe, the observations the VO kept. `exact_angles`: a tee's angle is held at
    the tee angle itself (no allowance; see `bundle.tee_angle_exact_codecs`)."""
    hold, attach = settings.bundle.tee_hold_keyframes, settings.bundle.tee_attach_keyframes
    out = pipe_map.copy()
    order = np.argsort(out.point_tracks)
    tids = out.point_tracks[order]
    by_number = {m.number: m for m in out.sections}
    reports = []
    for j in out.junctions:
        red, blue = by_number.get(j.before), by_number.get(j.after)
        if red is None or blue is None:
            reports.append(JoinReport(j.id, "kept the VO chaining: a straight section is missing on one side"))
            continue
        if red.end is None or blue.start is None:
            reports.append(JoinReport(j.id, "kept the VO chaining: no end cylinder on one side"))
            continue
        r_pose, b_pose = red.last, blue.first
        red_cyl, blue_cyl = red.end, blue.start
        if j.type == "elbow":
            r_pose, b_pose, red_cyl, blue_cyl = _beside_the_bend(out, j, red, blue, radius, settings)
        lo = max(red.first, r_pose - hold + 1)
        hi = min(blue.last, b_pose + attach - 1)
        sel, obs = _observations(out.keyframes, active, lo, hi, tids)
        n = hi - lo + 1
        if len(sel) < 30:
            reports.append(JoinReport(j.id, f"kept the VO chaining: only {len(sel)} points seen in the junction"))
            continue
        rows = order[sel]  # the junction's points in the map
        try:
            res, free = _solve_pass(out, j, rows, obs, (lo, hi, r_pose, b_pose), red_cyl, blue_cyl, camera, radius,
                                    settings, exact_angles, (red.cylinder, blue.cylinder))
        except (ValueError, np.linalg.LinAlgError) as exc:
            reports.append(JoinReport(j.id, f"kept the VO chaining: the tee solve failed ({exc})"))
            continue
        if not (res.converged or np.isfinite(res.rms_px)) or not np.all(np.isfinite(res.poses)):
            reports.append(JoinReport(j.id, "kept the VO chaining: the tee solve did not converge"))
            continue
        T = res.blue_transform
        moved = np.linalg.norm(res.blue_pose[:3, 3] - out.poses[b_pose, :3, 3])
        angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1)))
        # The blue section and everything after it move rigidly; the junction's own poses and points take
        # the solve's values.
        out.move_after(min(b_pose, blue.first) - 1, T)  # the whole blue section, its cylinders with it
        out.poses[lo:hi + 1] = res.poses
        good = res.point_inliers & np.all(np.isfinite(res.points), axis=1)
        out.points[rows[good]] = res.points[good]
        j.centroid = np.asarray(res.intersection, float)
        j.method = "elbow" if j.type == "elbow" else "tee-model"
        j.through = res.through
        j.angle_deg = float(res.model.angle_deg)
        if j.type == "elbow":
            j.bend_radius_m = float(res.bend_radius_m) if np.isfinite(res.bend_radius_m) else j.bend_radius_m
            j.modelled = True
            solved = model_bend(res.model, res.poses[r_pose - lo])
            j.axes = np.stack([solved.d1, solved.d2])
        reports.append(JoinReport(j.id, "tee-model", n, len(sel), len(obs), float(res.rms_px),
                                  float(res.cylinder_rms_m), float(res.model.angle_deg), float(moved), float(angle),
                                  float(res.time_s + (free.time_s if res is not free else 0.0)),
                                  float(free.model.angle_deg), res is not free, float(free.rms_px),
                                  _off_tee_angle(free.model.angle_deg, settings) if res is not free else float("nan")))
    return out, reports


def _solve_pass(out: PipeMap, j, rows: np.ndarray, obs: Observations, span: tuple[int, int, int, int], red_cyl,
                blue_cyl, camera: CameraModel, radius: float, settings: Settings, exact_angles: bool,
                whole=(None, None)):
    """(the junction solve's result, its free solve): keyframes lo..hi with P_r, P_b at r_pose, b_pose (`span`),
    the map's points `rows`. A tee whose free angle lies off its tee angle (`_held_angle`) is solved again from
    the free solution with the angle held."""
    lo, hi, r_pose, b_pose = span
    on_wall, on_bend, rho = None, None, None
    if j.type == "elbow":
        rho = j.bend_radius_m if np.isfinite(j.bend_radius_m) else 4.0 * radius
        bend = bend_of(red_cyl, blue_cyl, j.centroid)
        on_wall = ~on_arc(out.points[rows], bend, rho, margin_deg=-ARC_MARGIN_DEG)
        # the torus term takes the points well inside the arc; those at its ends could be the straight pipe's
        on_bend = on_arc(out.points[rows], bend, rho)
    fixed = [k - lo for k in range(lo, r_pose)]
    attached = [k - lo for k in range(b_pose + 1, hi + 1)]

    def solve(poses, points, red, blue, model=None, angle=None):
        return solve_junction(camera, poses, points, obs, red, blue,
                              red_pose=r_pose - lo, blue_pose=b_pose - lo, fixed=fixed, attached=attached,
                              radius=radius, settings=settings, cylinder_points=on_wall, torus_points=on_bend,
                              bend_radius=rho if settings.bundle.elbow_torus else None,
                              free_red_axis=settings.bundle.elbow_free_red_axis,
                              through=None if j.type == "elbow" else "auto", model=model, angle=angle)

    res = free = solve(out.poses[lo:hi + 1], out.points[rows], red_cyl, blue_cyl)
    held = None if j.type == "elbow" else _held_angle(free.model.angle_deg, settings, exact_angles)
    if held is not None and np.isfinite(free.rms_px) and np.all(np.isfinite(free.poses)):
        # from the free solve, which the held one refines
        points = np.where(np.isfinite(free.points), free.points, out.points[rows])
        red_axis, blue_axis = _held_axes((red_cyl, blue_cyl), whole, settings,
                                         (out.poses[r_pose, :3, 3], out.poses[b_pose, :3, 3]))
        if red_axis is red_cyl and blue_axis is blue_cyl:  # the end cylinders as the free model has them
            res = solve(free.poses, points, free.model.red, free.model.blue, free.model, np.radians(held))
        else:  # world cylinders; the blue one where the free solve put its section
            res = solve(free.poses, points, red_axis, moved_cylinder(free.blue_transform, blue_axis), None,
                        np.radians(held))
        res.blue_transform = res.blue_transform @ free.blue_transform
    return res, free


def _held_axes(ends, whole, settings: Settings, pivots=(None, None)):
    """(red, blue) cylinders a held tee angle lies between (`bundle.tee_hold_axes`): the end cylinders, or their
    sections' whole axes' directions, or (auto) each side's end cylinder unless it turns from its section's whole
    axis by more than bundle.tee_angle_allowance_deg, more than a joint deflects: there the VO's cameras bent the
    section's end (paper-loop route A as H.264 seed 3: the section after T3 1.5 deg off its axis over its first
    metre). A whole axis's direction is turned onto the end cylinder's axis where it passes nearest the end camera
    (`pivots`, its centre): the pipe lies where the end fit saw it and runs the way the section does."""
    mode = settings.bundle.tee_hold_axes
    out = []
    for end, axis, pivot in zip(ends, whole, pivots):
        if mode == "ends" or axis is None or end is None:
            out.append(end)
            continue
        a, b = end.direction / np.linalg.norm(end.direction), axis.direction / np.linalg.norm(axis.direction)
        bend = np.degrees(np.arccos(np.clip(abs(float(a @ b)), -1.0, 1.0)))
        if mode == "auto" and bend <= settings.bundle.tee_angle_allowance_deg:
            out.append(end)
            continue
        at = end.origin if pivot is None else end.origin + a * float((np.asarray(pivot) - end.origin) @ a)
        out.append(Cylinder(at, b if a @ b >= 0 else -b, end.radius))
    return out[0], out[1]


def _off_tee_angle(angle_deg: float, settings: Settings) -> float:
    """How far an angle lies from the nearest of bundle.tee_angles_deg (deg)."""
    return float(np.min(np.abs(np.asarray(settings.bundle.tee_angles_deg, float) - angle_deg)))


def _held_angle(free_deg: float, settings: Settings, exact: bool = False) -> float | None:
    """The angle (deg) a tee's solve is held at: the nearest of bundle.tee_angles_deg give or take
    bundle.tee_angle_allowance_deg (none if `exact`), where the free solve's angle lies beyond the allowance but
    within bundle.tee_angle_within_deg of it; else None (the free angle stands)."""
    b = settings.bundle
    allowance = 0.0 if exact else b.tee_angle_allowance_deg
    angles = np.asarray(b.tee_angles_deg, float)
    if not len(angles) or not np.isfinite(free_deg):
        return None
    near = float(angles[np.argmin(np.abs(angles - free_deg))])
    off = free_deg - near
    if abs(off) <= allowance or abs(off) > b.tee_angle_within_deg:
        return None
    return float(np.clip(near + np.sign(off) * allowance, 0.0, 179.999))


def _beside_the_bend(pipe_map: PipeMap, j, red, blue, radius: float, settings: Settings):
    """(P_r, P_b, C_r, C_b) of an elbow's solve: the red section's last keyframe before its bend begins and the
    blue one's first after the bend ends, each with its end cylinder fitted from there. A tight elbow looks
    straight again before the camera has left its arc (the next pipe's far end is back in view): its blue
    section starts up to a quarter of the arc early (0.11 m of a 45 deg elbow's 0.47 m), and a cylinder fitted
    over its first metre takes in some of the bend's wall. The keyframes in the arc are solved with the bend."""
    rho = j.bend_radius_m if np.isfinite(j.bend_radius_m) else 4.0 * radius
    bend = bend_of(red.end, blue.start, j.centroid)
    T = rho * np.tan(np.radians(bend.angle_deg) / 2)
    c = pipe_map.poses[:, :3, 3]
    before = np.arange(red.first, red.last + 1)
    before = before[(c[before] - (bend.vertex - T * bend.d1)) @ bend.d1 <= 0]
    after = np.arange(blue.first, blue.last + 1)
    after = after[(c[after] - (bend.vertex + T * bend.d2)) @ bend.d2 >= 0]
    r_pose = int(before[-1]) if len(before) else red.last
    b_pose = int(after[0]) if len(after) else blue.first
    fits = []
    for pose, end, sec, ends in ((r_pose, "last", red, red.end), (b_pose, "first", blue, blue.start)):
        if pose in (red.last, blue.first):
            fits.append(ends)
            continue
        ks = np.arange(sec.first, pose + 1) if end == "last" else np.arange(pose, sec.last + 1)
        order = np.argsort(pipe_map.point_tracks)
        pts = pipe_map.points[order[section_points(pipe_map.keyframes, int(ks[0]), int(ks[-1]),
                                                   pipe_map.point_tracks[order])]]
        try:
            fits.append(fit_end_cylinder(pipe_map.poses[ks], pts, radius, end=end,
                                          huber=settings.bundle.huber_m).cylinder)
        except (PipemapError, ValueError, np.linalg.LinAlgError):
            return red.last, blue.first, red.end, blue.start
    return r_pose, b_pose, fits[0], fits[1]


__all__ = ["JoinReport", "join_sections"]
