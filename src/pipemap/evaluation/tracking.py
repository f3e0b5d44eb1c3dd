"""Front-end results (trajectory.tum, tracks.csv, frames.csv, run.json) judged against ground truth.

- relative rotation / translation-direction error of consecutive keyframes;
- true correspondences: a track observation in keyframe k is ray-cast into the true pipe
  (network.yaml's nominal cylinders, or an exact `wall` function) from the true pose and
  re-projected into keyframe k+1; true when within 2 px. Also the fraction consistent with the
  true epipolar geometry (spherical Sampson distance under 2 px at the image centre), which
  does not depend on the wall model;
- mean track length (keyframes) of tracks that stay in straight sections (camera farther than
  `junction_margin_m` from every junction centroid), counting tracks seen at least twice;
- keyframe gaps (largest / median spacing in images, and in true metres travelled).

It reads only files and ground truth; it does not import the estimators.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipemap.dataset import load_dataset
from pipemap.geometry.rotations import rotation_angle, skew
from pipemap.network import PipeNetwork
from pipemap.trajectory import read_tum

TRUE_MATCH_PX = 2.0


def raycast_network(network: PipeNetwork, origin: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First wall point of the network seen along unit `directions` (N, 3) from `origin` (3,): (points, hit)."""
    r = network.radius_m
    n = len(directions)
    best = np.full(n, np.inf)
    pieces = network.straight_pieces()  # an elbow's arc as chords within 0.1 mm of it
    for seg in pieces:
        a, u, length = seg.start, seg.axis, seg.length
        oc = origin - a
        d_perp = directions - np.outer(directions @ u, u)
        o_perp = oc - (oc @ u) * u
        qa = np.sum(d_perp * d_perp, axis=1)
        qb = 2.0 * d_perp @ o_perp
        qc = o_perp @ o_perp - r * r
        disc = qb * qb - 4 * qa * qc
        ok = (disc >= 0) & (qa > 1e-12)
        sq = np.sqrt(np.where(ok, disc, 0.0))
        for s in ((-qb - sq) / np.maximum(2 * qa, 1e-12), (-qb + sq) / np.maximum(2 * qa, 1e-12)):
            p = origin + s[:, None] * directions
            h = (p - a) @ u
            good = ok & (s > 1e-6) & (h >= -1e-6) & (h <= length + 1e-6) & (s < best)
            good &= ~_inside_other(network.radius_m, pieces, p, seg)
            best = np.where(good, s, best)
    hit = np.isfinite(best)
    return origin + np.where(hit, best, 0.0)[:, None] * directions, hit


def _inside_other(radius: float, pieces, p: np.ndarray, this) -> np.ndarray:
    inside = np.zeros(len(p), bool)
    for seg in pieces:
        if seg is this:
            continue
        h = (p - seg.start) @ seg.axis
        radial = np.linalg.norm((p - seg.start) - np.outer(h, seg.axis), axis=1)
        inside |= (radial < radius - 1e-6) & (h > 1e-6) & (h < seg.length - 1e-6)
    return inside


def _pixel_angle(camera) -> float:
    c = np.array([[camera.width / 2.0, camera.height / 2.0], [camera.width / 2.0 + 1.0, camera.height / 2.0]])
    b, _ = camera.unproject(c)
    return float(np.arccos(np.clip(b[0] @ b[1], -1.0, 1.0)))


def _sampson(E: np.ndarray, bi: np.ndarray, bj: np.ndarray) -> np.ndarray:
    """Angular (spherical Sampson) distance of bearing pairs from the epipolar geometry E."""
    Ebi, Etbj = bi @ E.T, bj @ E
    e = np.sum(bj * Ebi, axis=1)
    gj = Ebi - np.sum(Ebi * bj, axis=1, keepdims=True) * bj
    gi = Etbj - np.sum(Etbj * bi, axis=1, keepdims=True) * bi
    return np.abs(e) / np.sqrt(np.sum(gj * gj, axis=1) + np.sum(gi * gi, axis=1) + 1e-300)


def _read_tracks(path: Path) -> dict[str, np.ndarray]:
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {"track_id": data[:, 0].astype(np.int64), "keyframe": data[:, 1].astype(int),
            "index": data[:, 2].astype(int), "uv": data[:, 3:5], "guided": data[:, 5] > 0}


def evaluate_tracking(out_dir: Path, dataset_path: Path, junction_margin_m: float | None = None, wall=None) -> dict:
    """Figures of one front-end result folder against the dataset's ground truth.

    `wall(origin, directions) -> (points, hit)` ray-casts into the true pipe; by default the
    nominal cylinders of network.yaml.
    """
    out_dir, dataset = Path(out_dir), load_dataset(dataset_path)
    camera, fps = dataset.camera, dataset.fps
    truth = dataset.ground_truth_poses()
    network = dataset.network()
    est = read_tum(out_dir / "trajectory.tum")
    kf_index = np.rint(est.timestamps * fps).astype(int)
    R_true = truth.rotations[kf_index]
    c_true = truth.positions[kf_index]
    motion = _relative_motion_errors(est, R_true, c_true)
    rot_err, dir_err, moving = motion.rotation_deg, motion.direction_deg, motion.moving

    tracks = _read_tracks(out_dir / "tracks.csv")
    true_flags, epipolar_flags, reproj = _true_correspondences(tracks, camera, network, wall, R_true, c_true, motion)

    margin = 2.5 * network.radius_m if junction_margin_m is None else junction_margin_m
    counts, straight = _straight_track_lengths(tracks, network, c_true, margin)
    gaps = np.diff(kf_index)
    # In metres travelled too: a slow start (the robot accelerating) spreads keyframes over more images.
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(truth.positions, axis=0), axis=1))])
    gaps_m = np.diff(travelled[kf_index])
    run = json.loads((out_dir / "run.json").read_text()) if (out_dir / "run.json").exists() else {}
    return {
        "images": int(len(truth)),
        "keyframes": int(len(kf_index)),
        "rotation_error_deg_median": float(np.median(rot_err)) if rot_err.size else None,
        "rotation_error_deg_p90": float(np.percentile(rot_err, 90)) if rot_err.size else None,
        "direction_error_deg_median": float(np.median(dir_err[moving])) if moving.any() else None,
        "direction_error_deg_p90": float(np.percentile(dir_err[moving], 90)) if moving.any() else None,
        "correspondences": int(true_flags.size),
        "true_correspondence_fraction": float(true_flags.mean()) if true_flags.size else None,
        "epipolar_consistent_fraction": float(epipolar_flags.mean()) if epipolar_flags.size else None,
        "reprojection_error_px_median": float(np.median(reproj)) if reproj.size else None,
        "mean_track_length_straight": float(counts[straight].mean()) if straight.any() else None,
        "mean_track_length_all": float(counts[counts >= 2].mean()) if (counts >= 2).any() else None,
        "keyframe_gap_median": float(np.median(gaps)) if gaps.size else None,
        "keyframe_gap_max": int(gaps.max()) if gaps.size else None,
        "keyframe_gap_m_median": float(np.median(gaps_m)) if gaps.size else None,
        "keyframe_gap_m_max": float(gaps_m.max()) if gaps.size else None,
        "lost_keyframes": run.get("lost_keyframes"),
        "frames_per_second": run.get("frames_per_second"),
    }


@dataclass
class _RelativeMotion:
    """Consecutive keyframes' relative motion, X_k = R X_{k-1} + t, true and its errors."""

    rotation_deg: np.ndarray  # (K-1,) angle of the estimated relative rotation against the true one
    direction_deg: np.ndarray  # (K-1,) angle between the estimated and the true translation
    moving: np.ndarray  # (K-1,) the camera moved between the two keyframes
    R_true_rel: np.ndarray  # (K-1, 3, 3)
    t_true: np.ndarray  # (K-1, 3)


def _relative_motion_errors(est, R_true: np.ndarray, c_true: np.ndarray) -> _RelativeMotion:
    # X_k = R X_{k-1} + t for estimate and truth.
    R_est_rel = np.einsum("kji,kjl->kil", est.rotations[1:], est.rotations[:-1])
    R_true_rel = np.einsum("kji,kjl->kil", R_true[1:], R_true[:-1])
    rot_err = np.degrees(rotation_angle(np.einsum("kij,klj->kil", R_est_rel, R_true_rel)))
    t_est = np.einsum("kji,kj->ki", est.rotations[1:], est.positions[:-1] - est.positions[1:])
    t_true = np.einsum("kji,kj->ki", R_true[1:], c_true[:-1] - c_true[1:])
    cosang = np.sum(t_est * t_true, axis=1) / (np.linalg.norm(t_est, axis=1) * np.linalg.norm(t_true, axis=1) + 1e-300)
    dir_err = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    moving = np.linalg.norm(c_true[1:] - c_true[:-1], axis=1) > 1e-6
    return _RelativeMotion(rot_err, dir_err, moving, R_true_rel, t_true)


def _true_correspondences(tracks: dict[str, np.ndarray], camera, network: PipeNetwork, wall, R_true: np.ndarray,
                          c_true: np.ndarray, motion: _RelativeMotion) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each track observation continued in the next keyframe: whether it is true (ray-cast into the true pipe,
    `wall` or else the network's cylinders, from the true pose and re-projected within TRUE_MATCH_PX), whether it
    fits the true epipolar geometry, and its reprojection error (inf where the ray-cast missed)."""
    pixel = _pixel_angle(camera)
    true_flags, epipolar_flags, reproj = [], [], []
    for k in range(1, len(c_true)):
        a, b = tracks["keyframe"] == k - 1, tracks["keyframe"] == k
        common, ia, ib = np.intersect1d(tracks["track_id"][a], tracks["track_id"][b], return_indices=True)
        if common.size == 0:
            continue
        uv_a, uv_b = tracks["uv"][a][ia], tracks["uv"][b][ib]
        bearings, _ = camera.unproject(uv_a)
        world_dirs = bearings @ R_true[k - 1].T
        if wall is None:
            points, hit = raycast_network(network, c_true[k - 1], world_dirs)
        else:
            points, hit = wall(c_true[k - 1], world_dirs)
        px, valid = camera.project((points - c_true[k]) @ R_true[k])
        err = np.linalg.norm(px - uv_b, axis=1)
        true_flags.append(hit & valid & (err < TRUE_MATCH_PX))
        reproj.append(np.where(hit & valid, err, np.inf))
        bearings_b, _ = camera.unproject(uv_b)
        t = motion.t_true[k - 1]
        E = skew(t / max(np.linalg.norm(t), 1e-300)) @ motion.R_true_rel[k - 1]
        epipolar_flags.append(_sampson(E, bearings, bearings_b) < TRUE_MATCH_PX * pixel)
    true_flags = np.concatenate(true_flags) if true_flags else np.zeros(0, bool)
    epipolar_flags = np.concatenate(epipolar_flags) if epipolar_flags else np.zeros(0, bool)
    reproj = np.concatenate(reproj) if reproj else np.zeros(0)
    return true_flags, epipolar_flags, reproj


def _straight_track_lengths(tracks: dict[str, np.ndarray], network: PipeNetwork, c_true: np.ndarray,
                            margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Each track's length in keyframes, and which tracks stay in straight sections (every keyframe seeing them
    at least `margin` from every junction centroid) and are seen at least twice."""
    if network.junctions:
        centroids = np.array([j.centroid for j in network.junctions])
        near = np.min(np.linalg.norm(c_true[:, None, :] - centroids[None], axis=2), axis=1) < margin
    else:
        near = np.zeros(len(c_true), bool)
    ids, counts = np.unique(tracks["track_id"], return_counts=True)
    kf_of_obs_near = near[tracks["keyframe"]]
    touched_junction = np.unique(tracks["track_id"][kf_of_obs_near])
    straight = ~np.isin(ids, touched_junction) & (counts >= 2)
    return counts, straight
