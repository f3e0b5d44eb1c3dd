"""Join the straight sections through their tees with the two-cylinder model (fisheye paper III-D).

The VO chains the sections through each junction with relative poses alone. Here, tee by tee in
the order the camera passes them, the junction's keyframes, the points they see and the tee
parameters Phi are bundle-adjusted with both pipes' cylinders (`pipemap.backend.junction`): the
straight section before the tee (red) is held, with its last `hold` keyframes; the straight
section after it (blue) moves as one rigid body with Phi through its first pose P_b and first
`attach` keyframes. Everything the camera did after P_b then takes the same rigid correction,
so the next tee starts from the corrected place. The tee centre is the model's intersection
point I. A junction without a straight section on both sides, whose end cylinders could not be
fitted, or whose solve fails keeps the VO's chaining and its axes-based centre, and says why.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.backend.bundle import Observations
from pipemap.backend.junction import solve_junction
from pipemap.backend.network_map import MappedJunction, MappedSection
from pipemap.backend.straight import StraightResult
from pipemap.camera.base import CameraModel
from pipemap.config import Settings
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


def _rigid(T: np.ndarray, poses: np.ndarray) -> np.ndarray:
    return T @ poses


def _move_cylinder(T: np.ndarray, c: Cylinder | None) -> Cylinder | None:
    return None if c is None else Cylinder(T[:3, :3] @ c.origin + T[:3, 3], T[:3, :3] @ c.direction, c.radius)


def join_sections(result: StraightResult, keyframes: list[Keyframe], sections: list[MappedSection],
                  junctions: list[MappedJunction], camera: CameraModel, radius: float,
                  settings: Settings) -> tuple[np.ndarray, np.ndarray, list[JoinReport]]:
    """Corrected poses (N, 4, 4) and points (M, 3, in the order of result.points), and a report per
    junction; `junctions[i].centroid` is set to the model's I where the solve succeeds."""
    hold, attach = settings.bundle.tee_hold_keyframes, settings.bundle.tee_attach_keyframes
    poses = result.poses.copy()
    order = np.argsort(result.point_tracks)
    tids = result.point_tracks[order]
    points = result.points[order].copy()
    first_seen = np.full(len(tids), len(poses), np.int64)
    for k, kf in enumerate(keyframes):
        p = np.searchsorted(tids, kf.track_ids)
        ok = p < len(tids)
        ok[ok] = tids[p[ok]] == kf.track_ids[ok]
        first_seen[p[ok]] = np.minimum(first_seen[p[ok]], k)
    by_number = {m.number: m for m in sections}
    reports = []
    for j in junctions:
        red, blue = by_number.get(j.before), by_number.get(j.after)
        if red is None or blue is None:
            reports.append(JoinReport(j.id, "kept the VO chaining: a straight section is missing on one side"))
            continue
        if red.end is None or blue.start is None:
            reports.append(JoinReport(j.id, "kept the VO chaining: no end cylinder on one side"))
            continue
        r_pose, b_pose = red.last, blue.first
        lo = max(red.first, r_pose - hold + 1)
        hi = min(blue.last, b_pose + attach - 1)
        sel, obs = _observations(keyframes, result.active, lo, hi, tids)
        n = hi - lo + 1
        if len(sel) < 30:
            reports.append(JoinReport(j.id, f"kept the VO chaining: only {len(sel)} points seen in the junction"))
            continue
        fixed = [k - lo for k in range(lo, r_pose)]
        attached = [k - lo for k in range(b_pose + 1, hi + 1)]
        try:
            res = solve_junction(camera, poses[lo:hi + 1], points[sel], obs, red.end, blue.start,
                                 red_pose=r_pose - lo, blue_pose=b_pose - lo, fixed=fixed, attached=attached,
                                 radius=radius, settings=settings)
        except (ValueError, np.linalg.LinAlgError) as exc:
            reports.append(JoinReport(j.id, f"kept the VO chaining: the tee solve failed ({exc})"))
            continue
        if not (res.converged or np.isfinite(res.rms_px)) or not np.all(np.isfinite(res.poses)):
            reports.append(JoinReport(j.id, "kept the VO chaining: the tee solve did not converge"))
            continue
        T = res.blue_transform
        moved = np.linalg.norm(res.blue_pose[:3, 3] - poses[b_pose, :3, 3])
        angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1)))
        # Everything after P_b moves rigidly; the junction's own poses and points take the solve's values.
        poses[hi + 1:] = _rigid(T, poses[hi + 1:])
        poses[lo:hi + 1] = res.poses
        later = first_seen > hi
        points[later] = points[later] @ T[:3, :3].T + T[:3, 3]
        blue_only = (first_seen >= b_pose) & (first_seen <= hi)
        blue_only[sel] = False
        points[blue_only] = points[blue_only] @ T[:3, :3].T + T[:3, 3]
        good = res.point_inliers & np.all(np.isfinite(res.points), axis=1)
        points[sel[good]] = res.points[good]
        for m in sections:
            if m.first > r_pose:
                m.cylinder, m.start, m.end = (_move_cylinder(T, c) for c in (m.cylinder, m.start, m.end))
                if m.bend is not None:  # knots are axial coordinates and move with the axis; offsets are world vectors
                    m.bend = (m.bend[0], m.bend[1] @ T[:3, :3].T)
                if m.cylinder is not None:
                    h = m.cylinder.axial(poses[[m.first, m.last], :3, 3])
                    m.start_h, m.end_h = float(h[0]), float(h[1])
        for later_j in junctions:
            if later_j.first > j.last:
                later_j.centroid = T[:3, :3] @ later_j.centroid + T[:3, 3]
        j.centroid = np.asarray(res.intersection, float)
        j.method = "tee-model"
        j.through = res.through
        j.angle_deg = float(res.model.angle_deg)
        reports.append(JoinReport(j.id, "tee-model", n, len(sel), len(obs), float(res.rms_px),
                                  float(res.cylinder_rms_m), float(res.model.angle_deg), float(moved), float(angle),
                                  float(res.time_s)))
    out = np.empty_like(points)
    out[order] = points
    return poses, out, reports


__all__ = ["JoinReport", "join_sections"]
