"""Self-checks of the network pipeline's sections, from the run's own figures (no ground truth).

Straight sections: the window solves' reprojection RMS and wall residual, the tracked fraction of
the keyframes, whether the section has a metric scale at all, and the free radius: the section's
tracks triangulated from its final poses alone, with no wall term, lie at a radius that scales
with the poses' translations, so a wrong scale shows as a radius off the given one. Junction
sections: how the junction was placed (two axes meeting, the tee model, or only the camera path).
The run: loop closure's largest correction and the stretches where tracking was lost, which the
trajectory does not bridge.
"""

from __future__ import annotations

import math

import numpy as np

from pipemap.backend.free_points import free_points
from pipemap.backend.network_map import stretch_cylinder
from pipemap.config import QualitySettings
from pipemap.frontend.image_steps import step_disagreement
from pipemap.quality.verdict import FAILED, GOOD, SUSPECT, Check, RunVerdict, SectionVerdict, above, below

_MIN_PARALLAX_DEG = 2.0  # tracks seen over less are too poorly triangulated to say anything about the radius
FREE_RADIUS_STRETCH_RADII = 40.0  # a longer section's free radius is taken against the axes of stretches this long


def free_radius(keyframes, poses: np.ndarray, first: int, last: int, axis_origin: np.ndarray,
                axis_direction: np.ndarray, min_points: int) -> tuple[float | None, int]:
    """Median distance from the axis of the tracks seen by keyframes first..last, each triangulated
    (least-squares ray intersection) from the final poses alone; (None, n) with fewer than min_points."""
    dist = free_distances(keyframes, poses, first, last, axis_origin, axis_direction)
    return (float(np.median(dist)) if len(dist) >= min_points else None), len(dist)


def free_distances(keyframes, poses: np.ndarray, first: int, last: int, axis_origin: np.ndarray,
                   axis_direction: np.ndarray) -> np.ndarray:
    """Distances from the axis of the tracks seen by keyframes first..last (three rays or more, 2 degrees of
    parallax), each the midpoint of its rays from the final poses alone (`backend.free_points`)."""
    kfs = [keyframes[k] for k in range(first, last + 1)]
    ids = [kf.track_ids for kf in kfs if len(kf.track_ids)]
    if not ids:
        return np.zeros(0)
    ids, counts = np.unique(np.concatenate(ids), return_counts=True)
    X, valid = free_points(kfs, poses[first:last + 1], ids[counts >= 3], min_parallax_deg=_MIN_PARALLAX_DEG,
                           max_ray_error_deg=np.inf, min_views=3, refine_iterations=0)
    u = axis_direction / np.linalg.norm(axis_direction)
    rel = X[valid] - axis_origin
    return np.linalg.norm(rel - np.outer(rel @ u, u), axis=1)


def section_free_radius(keyframes, poses: np.ndarray, first: int, last: int, whole, radius: float, min_points: int,
                        wall: tuple[np.ndarray, np.ndarray, float] | None = None) -> tuple[float | None, int]:
    """free_radius of a straight section against its mapped cylinder `whole`; with `wall` (the map's points
    and their track ids, sorted by id, and the Huber threshold of the sections' cylinder fits), a section longer
    than FREE_RADIUS_STRETCH_RADII radii is taken a stretch of about that length at a time, each against the
    cylinder of the map's points along it, and the distances pooled: over tens of metres the slow heading drift
    of a mapped run bends its pipe by centimetres, off any one straight axis (a 64 m section had read 7 % off the
    given radius)."""
    path = _path_length(poses, first, last, cumulative=True)
    span = FREE_RADIUS_STRETCH_RADII * radius
    if wall is None or path[-1] <= span:
        return free_radius(keyframes, poses, first, last, whole.origin, whole.direction, min_points)
    bounds = first + np.searchsorted(path, np.linspace(0.0, path[-1], math.ceil(path[-1] / span) + 1))
    bounds[-1] = last + 1
    dist = []
    for k0, k1 in zip(bounds[:-1], bounds[1:] - 1):
        if k1 - k0 < 2:
            continue
        fit = stretch_cylinder(keyframes, poses, int(k0), int(k1), wall[1], wall[0], radius, wall[2])
        axis = whole if fit is None else fit.cylinder
        dist.append(free_distances(keyframes, poses, int(k0), int(k1), axis.origin, axis.direction))
    dist = np.concatenate(dist) if dist else np.zeros(0)
    return (float(np.median(dist)) if len(dist) >= min_points else None), len(dist)


def _path_length(poses: np.ndarray, first: int, last: int, cumulative: bool = False):
    """The camera path's length from keyframe first to last, or its length at each of them."""
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[first:last + 1, :3, 3], axis=0), axis=1))])
    return path if cumulative else float(path[-1])


def network_verdict(vo_sections, windows, keyframes, poses: np.ndarray, mapped_sections, junctions, joins, revisit,
                    radius: float, q: QualitySettings, route_length_m: float,
                    wall: tuple[np.ndarray, np.ndarray, float] | None = None, dropped=()) -> RunVerdict:
    """The rating of every VO section of a network run and of the run's loop closure. `wall`: the map's points
    and their track ids and the sections' Huber threshold (bundle.huber_m), which give long sections' free radius
    stretch by stretch (section_free_radius). `dropped`: the junction passes dropped for showing no junction
    (backend/evidence.DroppedPass), whose turn the map keeps."""
    mapped = {m.number: m for m in mapped_sections}
    if wall is not None and any(_path_length(poses, s.first, s.last) > FREE_RADIUS_STRETCH_RADII * radius
                                for s in vo_sections if s.kind == "straight"):
        order = np.argsort(wall[1])
        wall = (wall[0][order], wall[1][order], wall[2])
    else:
        wall = None
    by_section: dict[int, list] = {}
    for w in windows:
        by_section.setdefault(w.section, []).append(w)
    junction_of = {(j.first, j.last): j for j in junctions}
    join_of = {r.junction: r for r in joins}
    dropped_of = {(d.first, d.last): d for d in dropped}
    out, gaps = [], []
    for s in vo_sections:
        kfs = keyframes[s.first:s.last + 1]
        v = SectionVerdict(s.number, s.kind, int(kfs[0].index), int(kfs[-1].index), s.last - s.first + 1)
        if s.number > 0 and not s.linked:
            prev = keyframes[s.first - 1]
            gaps.append({"after_frame": int(prev.index), "before_frame": int(kfs[0].index), "section": s.number})
            v.checks.append(Check("tracking", None, SUSPECT, f"tracking was lost before it (frames {prev.index}-"
                                  f"{kfs[0].index}): its place relative to the map before is not known"))
        # the previous keyframe's features that go on as tracks consistent with the relative pose: how many do
        # depends on the lens (a forward camera loses its rim every step), so a section is judged against the run
        pairs = ((keyframes[k - 1], keyframes[k]) for k in range(max(s.first, 1), s.last + 1))
        tracked = [kf.inliers.sum() / len(prev) for prev, kf in pairs if kf.pose_valid and len(prev)]
        v.figures["tracked_fraction"] = float(np.median(tracked)) if tracked else None
        if s.kind == "straight":
            _straight_checks(v, s, by_section.get(s.number, []), keyframes, poses, mapped.get(s.number), radius, q,
                             wall)
        else:
            j = junction_of.get((s.first, s.last))
            d = dropped_of.get((s.first, s.last))
            if j is None and d is not None and np.isfinite(d.angle_deg):
                v.checks.append(above("unexplained turn", d.angle_deg, (q.unexplained_turn_deg, math.inf),
                                      f"the axes turn across it where nothing branches ({d.id} dropped), by",
                                      fmt=lambda x: f"{x:.1f} deg"))
            if j is not None:
                v.figures["junction"] = j.id
                v.figures["placed_by"] = j.method
                if j.method == "path":
                    v.checks.append(Check("junction evidence", None, SUSPECT, f"{j.id} has a straight section on "
                                          "one side only: its centre follows the camera path"))
                r = join_of.get(j.id)
                if r is not None and r.status != "tee-model":
                    v.checks.append(Check("tee model", None, SUSPECT, f"{j.id}'s tee model was not solved "
                                          f"({r.status})"))
                if r is not None and r.angle_held:
                    v.figures["tee_free_angle_deg"] = r.free_angle_deg
                    off = r.free_angle_off_deg
                    v.checks.append(Check("tee angle", off, SUSPECT if off > q.tee_angle_off_deg else GOOD,
                                          "" if off <= q.tee_angle_off_deg else
                                          f"{j.id}'s free solve turned {off:.2f} deg from a tee's angle (limit "
                                          f"{q.tee_angle_off_deg:g}): held at {r.angle_deg:.2f} deg"))
        out.append(v)
    run_tracked = [v.figures["tracked_fraction"] for v in out if v.figures.get("tracked_fraction") is not None]
    if run_tracked:
        typical = float(np.median(run_tracked))
        for v in out:
            f = v.figures.get("tracked_fraction")
            v.checks.append(below("tracking", None if f is None or typical <= 0 else f / typical, q.tracked_share,
                                  "tracked fraction against the run's median", fmt=lambda x: f"{100 * x:.0f} %"))
    checks = []
    if revisit is not None and revisit.status == "closed" and route_length_m > 0:
        checks.append(above("loop closure", revisit.max_correction_m / route_length_m, q.loop_correction,
                            "loop closure moved a pose by a fraction of the route of",
                            fmt=lambda x: f"{100 * x:.2f} %"))
    return RunVerdict(out, checks, gaps)


def _straight_checks(v: SectionVerdict, s, windows, keyframes, poses, mapped, radius: float, q: QualitySettings,
                     wall=None):
    if v.keyframes < q.min_keyframes:
        v.checks.append(Check("keyframes", v.keyframes, SUSPECT, f"only {v.keyframes} keyframes"))
    if s.scale == "unit":
        v.checks.append(Check("scale", None, FAILED, "no metric scale: no window could be solved"))
    elif s.scale == "assumed":
        v.checks.append(Check("scale", None, SUSPECT, "scale carried over from the section before (no window "
                              "solve of its own)"))
    rms = [w.rms_px for w in windows if np.isfinite(w.rms_px)]
    cyl = [w.cylinder_rms_m for w in windows if np.isfinite(w.cylinder_rms_m)]
    v.figures["windows"] = len(windows)
    v.figures["rms_px"] = float(np.median(rms)) if rms else None
    v.figures["cylinder_rms_m"] = float(np.median(cyl)) if cyl else None
    v.checks.append(above("reprojection", v.figures["rms_px"], q.rms_px, "reprojection RMS (px)"))
    v.checks.append(above("wall residual", None if not cyl else v.figures["cylinder_rms_m"] / radius, q.cylinder_rms,
                          "wall residual, fraction of the radius,", fmt=lambda x: f"{100 * x:.1f} %"))
    r_free, n = (None, 0)
    if mapped is not None and mapped.cylinder is not None:
        r_free, n = section_free_radius(keyframes, poses, s.first, s.last, mapped.cylinder, radius,
                                        q.min_free_radius_points, wall)
    v.figures["image_step_factor"] = step_disagreement(keyframes, poses, s.first, s.last, radius,
                                                      q.image_step_keyframes,
                                                      None if mapped is None else mapped.cylinder)
    v.checks.append(above("image motion", v.figures["image_step_factor"], q.image_step,
                          "keyframe steps differ from the image motion's by a factor of", fmt=lambda x: f"{x:.2f}"))
    v.figures["free_radius_m"] = r_free
    v.figures["free_radius_points"] = n
    v.checks.append(above("free radius", None if r_free is None else abs(r_free / radius - 1), q.free_radius,
                          "free radius is off the given one by", fmt=lambda x: f"{100 * x:.1f} %"))


__all__ = ["free_radius", "free_distances", "section_free_radius", "network_verdict"]
