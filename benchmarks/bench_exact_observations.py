"""Where a simulated run's error comes from: the back end on the tracked observations, on exact ones, and on exact
ones plus one part of the tracking's errors.

    python benchmarks/bench_exact_observations.py DATASET [DATASET ...] [--parts all exact along across top bottom]
                                                      [--set section.key=value ...]

For each simulated dataset folder it runs the network pipeline's front end once, puts every track's point where the
ray of its first observation from the TRUE pose meets the true wall (the union of the network's pipes, openings
left open; ground_truth/network.yaml), and projects that point into every keyframe of the track with the true poses.
Tracks whose first ray meets no wall (an end cap, a junction's odd corner) keep their tracked observations. The
network back end (`map_network`, as `pipemap run` runs it) then runs on each part:
- all: the tracked observations; exact: the exact projections;
- along / across: exact plus the tracking's error along / across each track's image motion since its previous
  observation; top / bottom: exact plus the error of the observations in the upper / lower half of the image;
  early / late: exact plus the error of each track's second and third / fourth and later observations;
  early-along / early-across / late-along / late-across: the same, only the error's part along / across the motion;
  inner / rim: exact plus the error of the observations within / beyond 85 deg of the optical axis;
  inner-along / rim-along: the same, only the error's part along the motion;
  noise: exact plus independent Gaussian noise of --noise-px (seeded);
  turns-exact: the tracked observations, exact in the keyframes within --turn-reach keyframes of one that turns
  --turn-deg (2) or more from the one before (where a junction's angle is set; a sweeping bend turns less);
  with --on SEGMENT..., the pixel parts add their error only to the tracks whose point lies on those segments of
  the network (a cross's other pipes seen through its openings, say), the rest exact;
  debiased / debiased-sector / debiased-colatitude: the tracked observations less the mean error along the motion
  of their place in the track (and 45 deg sector about the image centre, or band of colatitude), measured over the
  run: what a bias model per track age would gain at best.
A forward-and-reverse run reports the distance driven forward (start to the farthest keyframe) and back against the
truth; any other the Sim(3) scale of the keyframe positions, the ATE after it, every distance between junction
centres, each elbow's angle and each tee solve's angle (and its free angle). It also prints the tracking's error
along and across the motion by place in the track (mean, RMS and median absolute value), and its mean along the
motion by the direction of the observation from the image centre (45 degree sectors, image y pointing down), by
colatitude and by the keyframe's true turn from the one before, relative to each track's first observation; and
the rotation each keyframe's young tracks' error implies (`frame_rotations`: a decoded picture whose content sits
off as a whole), by turn and summed over each turn. No scale alignment anywhere. Writes
benchmarks/results/exact_observations.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipemap.config import load_settings
from pipemap.dataset import load_dataset
from pipemap.network import load_network
from pipemap.pipeline import map_network, track_and_classify
from pipemap.trajectory import read_tum

PIXEL_PARTS = ("all", "exact", "along", "across", "top", "bottom", "early", "late", "inner", "rim", "early-along",
               "early-across", "late-along", "late-across", "inner-along", "rim-along")
PARTS = PIXEL_PARTS + ("debiased", "debiased-sector", "debiased-colatitude", "noise", "turns-exact")
_RIM_DEG = 85.0


def wall_points(pieces, radius: float, origin: np.ndarray, rays: np.ndarray, which: bool = False):
    """(N, 3): where each ray (N, 3) from `origin` first meets the wall of the union of the pipes `pieces`
    (straight segments), NaN where it meets none; with `which`, also (N,) the index of the piece met (-1: none)."""
    rays = np.asarray(rays, float).reshape(-1, 3)
    best = np.full((len(rays), 3), np.nan)
    nearest = np.full(len(rays), np.inf)
    met = np.full(len(rays), -1)
    for index, piece in enumerate(pieces):
        a = piece.axis / np.linalg.norm(piece.axis)
        v = origin - piece.start
        vp, dp = v - (v @ a) * a, rays - (rays @ a)[:, None] * a
        qa, qb, qc = np.einsum("ij,ij->i", dp, dp), 2 * dp @ vp, vp @ vp - radius * radius
        with np.errstate(invalid="ignore", divide="ignore"):
            lam = (-qb + np.sqrt(qb * qb - 4 * qa * qc)) / (2 * qa)
        p = origin + lam[:, None] * rays
        h = (p - piece.start) @ a
        hit = np.isfinite(lam) & (lam > 0) & (lam < nearest) & (h >= 0) & (h <= piece.length)
        for other in pieces:
            if other is not piece and hit.any():
                hit[hit] &= ~_inside(other, radius, p[hit])
        best[hit], nearest[hit], met[hit] = p[hit], lam[hit], index
    return (best, met) if which else best


def _inside(piece, radius: float, p: np.ndarray) -> np.ndarray:
    a = piece.axis / np.linalg.norm(piece.axis)
    w = p - piece.start
    h = w @ a
    return (1e-4 < h) & (h < piece.length - 1e-4) & (np.linalg.norm(w - h[:, None] * a, axis=1) < radius - 1e-5)


def exact_observations(front, camera, network, R: np.ndarray, C: np.ndarray) -> list[np.ndarray | None]:
    """Per keyframe: (N, 2) exact pixels of its observations, NaN where the track's point is unknown."""
    return exact_observations_on_pipes(front, camera, network, R, C)[0]


def exact_observations_on_pipes(front, camera, network, R: np.ndarray, C: np.ndarray):
    """exact_observations, and per keyframe (N,) the id of the network segment each observation's point lies on
    ('' where unknown; an arc's chords count as their arc)."""
    pieces = network.straight_pieces()
    names = np.array([p.id.split("#")[0] for p in pieces] + [""])  # index -1: none
    points: dict[int, np.ndarray] = {}
    pipe: dict[int, str] = {}
    out, on = [], []
    for k, kf in enumerate(front.keyframes):
        new = [row for row, tid in enumerate(kf.track_ids.tolist()) if tid not in points]
        found, met = wall_points(pieces, network.radius_m, C[k], kf.bearings[new] @ R[k].T, which=True)
        points.update(zip(kf.track_ids[new].tolist(), found))
        pipe.update(zip(kf.track_ids[new].tolist(), names[met]))
        on.append(np.array([pipe[t] for t in kf.track_ids.tolist()], dtype=object))
        X = np.array([points[t] for t in kf.track_ids.tolist()]).reshape(-1, 3)
        uv = np.full((len(X), 2), np.nan)
        known = np.all(np.isfinite(X), axis=1)
        if known.any():
            uv[known] = camera.project((X[known] - C[k]) @ R[k])[0]
        out.append(uv)
    return out, on


def motion_and_place(front, exact: list[np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per keyframe: each observation's unit image motion since its track's previous observation (zero for a
    first one) and its place in the track (0 = first), from the exact pixels."""
    previous: dict[int, np.ndarray] = {}
    place: dict[int, int] = {}
    motions, places = [], []
    for kf, uv in zip(front.keyframes, exact):
        m, p = np.zeros((len(uv), 2)), np.zeros(len(uv), int)
        for row, tid in enumerate(kf.track_ids.tolist()):
            if tid in previous:
                step = uv[row] - previous[tid]
                n = np.linalg.norm(step)
                m[row] = step / n if n > 0 else 0.0
                place[tid] += 1
            else:
                place[tid] = 0
            p[row] = place[tid]
            previous[tid] = uv[row]
        motions.append(m)
        places.append(p)
    return motions, places


def part_pixels(part: str, tracked: np.ndarray, exact: np.ndarray, motion: np.ndarray, place: np.ndarray,
                centre_v: float, colatitude: np.ndarray | None = None, on: np.ndarray | None = None) -> np.ndarray:
    """One keyframe's pixels for `part` (see the module docstring); `on` (N,) bool: only these observations take
    the part's error (--on)."""
    error = tracked - exact
    along = (error * motion).sum(axis=1)[:, None] * motion
    keep = {"all": np.ones(len(error), bool), "exact": np.zeros(len(error), bool),
            "top": exact[:, 1] < centre_v, "bottom": exact[:, 1] >= centre_v,
            "early": (place >= 1) & (place <= 2), "late": place >= 3}
    if colatitude is not None:  # degrees, of the exact pixels
        keep.update(inner=colatitude < _RIM_DEG, rim=colatitude >= _RIM_DEG)
    which, _, component = (f"all-{part}" if part in ("along", "across") else part).partition("-")
    added = {"along": along, "across": error - along, "": error}[component]
    chosen = keep[which] if on is None else keep[which] & on
    added = np.where(chosen[:, None], added, 0.0)
    out = exact + added
    return np.where(np.all(np.isfinite(exact), axis=1)[:, None], out, tracked)


_TURNS = (0.0, 0.5, 2.0, 4.0, 6.0, 8.0, 180.0)  # deg, bands of a keyframe's true rotation from the one before


def true_turns_deg(R: np.ndarray) -> np.ndarray:
    """(K,) each keyframe's true rotation from the keyframe before (deg; 0 for the first)."""
    cos = (np.einsum("kij,kij->k", R[:-1], R[1:]) - 1.0) / 2.0  # trace(R_{k-1}^T R_k) = sum of elementwise products
    return np.concatenate([[0.0], np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))])


def errors_by_turn(front, exact, motions, places, R: np.ndarray) -> dict:
    """The tracked error's mean along the motion by place in the track (1-6), for keyframes grouped by their true
    rotation from the keyframe before (deg): a turn through a junction against the straight runs."""
    turn = true_turns_deg(R)
    out = {}
    for lo, hi in zip(_TURNS[:-1], _TURNS[1:]):
        ks = np.flatnonzero((turn >= lo) & (turn < hi))
        if not len(ks):
            continue
        a = np.concatenate([((front.keyframes[k].keypoints - exact[k]) * motions[k]).sum(axis=1) for k in ks])
        p = np.concatenate([places[k] for k in ks])
        ok = (p > 0) & np.isfinite(a) & (np.abs(a) < 2)
        cells = {q: (float(a[sel].mean()), int(sel.sum())) for q in range(1, 7) if (sel := ok & (p == q)).any()}
        out[f"{lo:g}..{hi:g}"] = {"keyframes": len(ks), **cells}
    return out


def frame_rotations(front, camera, exact, places, R: np.ndarray) -> dict:
    """The part of each keyframe's tracked error that moves all its young observations alike: the small rotation
    (deg, camera axes x right, y down, z along the optical axis) that best explains the errors of the tracks one
    keyframe old (their first observation is exact by construction, so this is what the pair of keyframes sees as
    the rotation between them), least squares on unit bearings. Independent errors of 0.5 px over 250 points give
    about 0.01 deg; a decoded picture whose content sits off as a whole gives more. Mean and standard deviation by
    the keyframe's true turn from the one before, and the sum over each run of turning keyframes (a junction)."""
    rows, turns = [], true_turns_deg(R)
    for k, (kf, uv, q) in enumerate(zip(front.keyframes, exact, places)):
        ok = np.all(np.isfinite(uv), axis=1) & (q == 1)
        if k == 0 or ok.sum() < 20:
            continue
        tracked, seen = camera.unproject(kf.keypoints[ok])
        true, seen_true = camera.unproject(uv[ok])
        both = np.asarray(seen, bool) & np.asarray(seen_true, bool)
        tracked, true = tracked.reshape(-1, 3)[both], true.reshape(-1, 3)[both]
        # tracked - true = w x true = -[true]x w, stacked over the observations
        A = -np.cross(true[:, None, :], np.eye(3)[None, :, :]).transpose(0, 2, 1).reshape(-1, 3)
        w = np.linalg.lstsq(A, (tracked - true).ravel(), rcond=None)[0]
        rows.append((k, float(turns[k]), *np.degrees(w)))
    if not rows:
        return {}
    a = np.array(rows)
    out = {}
    for lo, hi in ((0.0, 0.5), (0.5, 4.0), (4.0, 180.0)):
        m = (a[:, 1] >= lo) & (a[:, 1] < hi)
        if m.any():
            out[f"{lo:g}..{hi:g}"] = {"keyframes": int(m.sum()), "mean_deg": a[m, 2:].mean(0).round(4).tolist(),
                                      "std_deg": a[m, 2:].std(0).round(4).tolist()}
    turning = a[a[:, 1] >= 4.0]
    if len(turning):
        runs = np.split(turning, np.flatnonzero(np.diff(turning[:, 0]) > 3) + 1)
        out["turns"] = [{"keyframes": [int(r[0, 0]), int(r[-1, 0])], "true_turn_deg": round(float(r[:, 1].sum()), 2),
                         "sum_deg": r[:, 2:].sum(0).round(3).tolist()} for r in runs]
    return out


def near_turns(R: np.ndarray, reach: int, turn_deg: float = 2.0) -> np.ndarray:
    """(K,) bool: the keyframes within `reach` keyframes of one whose true rotation from the keyframe before is
    `turn_deg` or more."""
    turning = np.flatnonzero(true_turns_deg(R) >= turn_deg)
    if not len(turning):
        return np.zeros(len(R), bool)
    return np.min(np.abs(np.arange(len(R))[:, None] - turning[None, :]), axis=1) <= reach


def noisy(keyframes, exact: list[np.ndarray], sigma_px: float, rng: np.random.Generator) -> list[np.ndarray]:
    """Per keyframe: the exact pixels plus independent Gaussian noise of `sigma_px`, the tracked ones where there
    is no exact projection."""
    return [np.where(np.isfinite(uv), uv + rng.normal(0.0, sigma_px, uv.shape), kf.keypoints)
            for kf, uv in zip(keyframes, exact)]


def mean_lag(front, camera, exact, motions, places, by: str) -> list[np.ndarray]:
    """Per keyframe: (N, 2) the mean tracked error along the motion of the observation's cell (its place in the
    track, 1..8 and 9 for later ones, and by "sector" its 45 deg sector about the image centre or by
    "colatitude" its band of colatitude) times its motion: what a bias model per track age (and sector or
    colatitude) would take out at best."""
    centre = np.array([camera.width - 1, camera.height - 1]) / 2

    def cells(uv, q):
        place = np.minimum(q, 9)
        if by == "sector":
            return place * 8 + sector(uv - centre)
        if by == "colatitude":
            return place * 8 + np.clip(np.searchsorted(_COLATITUDES, colatitude_deg(camera, uv)) - 1, 0, 7)
        return place
    total, count = np.zeros(80), np.zeros(80)
    keyed = [cells(np.nan_to_num(uv), q) for uv, q in zip(exact, places)]
    for kf, uv, m, q, c in zip(front.keyframes, exact, motions, places, keyed):
        a = ((kf.keypoints - uv) * m).sum(axis=1)
        ok = (q > 0) & np.isfinite(a) & (np.abs(a) < 2)
        np.add.at(total, c[ok], a[ok])
        np.add.at(count, c[ok], 1)
    mean = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return [np.where((q > 0)[:, None], mean[c][:, None] * m, 0.0) for m, q, c in zip(motions, places, keyed)]


def sector(d: np.ndarray) -> np.ndarray:
    """The 45 deg sector (0..7, from -180 deg, image y down) of offsets d (N, 2) from the image centre."""
    return np.floor((np.degrees(np.arctan2(d[:, 1], d[:, 0])) + 180) / 45).astype(int) % 8


def judged(net, G: np.ndarray, network) -> dict:
    """Forward / reverse distance (a run that turns back) or Sim(3) scale, ATE and junction distances."""
    P = net.map.poses[:, :3, 3]
    far = int(np.argmax(np.linalg.norm(G - G[0], axis=1)))
    if not network.junctions and 0 < far < len(G) - 1:
        def pct(a, b):
            g = np.linalg.norm(G[b] - G[a])
            return 100 * (np.linalg.norm(P[b] - P[a]) - g) / g
        return {"forward_pct": pct(0, far), "reverse_pct": pct(far, len(G) - 1)}
    mp, mg = P.mean(0), G.mean(0)
    U, S, Vt = np.linalg.svd((G - mg).T @ (P - mp))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    rot = U @ D @ Vt
    s = float((S * np.diag(D)).sum() / ((P - mp) ** 2).sum())
    ate = float(np.sqrt(np.mean(np.sum((s * (P - mp) @ rot.T - (G - mg)) ** 2, axis=1))))
    truth = np.array([j.centroid for j in network.junctions])
    found = [(np.asarray(j.centroid), int(np.argmin(np.linalg.norm(truth - (s * (np.asarray(j.centroid) - mp) @ rot.T
                                                                            + mg), axis=1)))) for j in net.tees]
    pairs = [100 * (np.linalg.norm(a - b) / np.linalg.norm(truth[i] - truth[j]) - 1)
             for n, (a, i) in enumerate(found) for b, j in found[n + 1:] if i != j]
    return {"sim3_scale": s, "ate_mm": 1000 * ate, "junction_distances_pct": pairs,
            "max_abs_pct": float(np.max(np.abs(pairs))) if pairs else None,
            "elbow_angles_deg": [round(float(j.angle_deg), 3) for j in net.tees if j.type == "elbow"],
            "tee_solves": [f"{r.junction} {r.angle_deg:.3f} (free {r.free_angle_deg:.3f})" for r in net.joins]}


_COLATITUDES = (0, 30, 45, 60, 70, 80, 85, 90, 180)  # deg, bands of the mean error along the motion by colatitude
_PLACE_GROUPS = ((1, 2), (3, 4), (5, 6), (7, 8))


def colatitude_deg(camera, pixels: np.ndarray) -> np.ndarray:
    """Degrees from the optical axis of pixels (N, 2)."""
    bearings, _ = camera.unproject(pixels)
    return np.degrees(np.arccos(np.clip(bearings.reshape(-1, 3)[:, 2], -1.0, 1.0)))


def errors_by_place_and_sector(front, camera, exact, motions, places) -> dict:
    """The tracked error (px) along the motion and across it (the motion turned +90 deg in the image, y down: the
    same sense of rotation about the image centre for a camera moving forward) by place in the track, as mean,
    RMS and median absolute value; its mean along the motion by 45 deg sector around the image's centre, and by
    band of colatitude (the angle from the optical axis) for places 1-2, 3-4, 5-6 and 7-8."""
    cam_centre = np.array([camera.width - 1, camera.height - 1]) / 2
    a_, c_, p, sec, col = [], [], [], [], []
    for kf, uv, m, q in zip(front.keyframes, exact, motions, places):
        error = kf.keypoints - uv
        a = (error * m).sum(axis=1)
        c = error[:, 1] * m[:, 0] - error[:, 0] * m[:, 1]
        ok = (q > 0) & np.isfinite(a) & (np.abs(a) < 2) & (np.abs(c) < 2)
        a_.append(a[ok])
        c_.append(c[ok])
        p.append(q[ok])
        sec.append(sector(uv[ok] - cam_centre))
        col.append(colatitude_deg(camera, uv[ok]))
    a, c, p, sectors, col = (np.concatenate(x) for x in (a_, c_, p, sec, col))
    places_ = [q for q in range(1, 9) if (p == q).any()]
    by_colatitude = {}
    for lo, hi in zip(_COLATITUDES[:-1], _COLATITUDES[1:]):
        band = (col >= lo) & (col < hi)
        cells = {f"{g0}-{g1}": (float(a[sel].mean()), int(sel.sum()))
                 for g0, g1 in _PLACE_GROUPS if (sel := band & (p >= g0) & (p <= g1)).any()}
        if cells:
            by_colatitude[f"{lo}..{hi}"] = cells
    return {
        "along_motion_px_by_place": {q: float(a[p == q].mean()) for q in places_},
        "across_motion_px_by_place": {q: float(c[p == q].mean()) for q in places_},
        "along_rms_px_by_place": {q: float(np.sqrt(np.mean(a[p == q] ** 2))) for q in places_},
        "across_rms_px_by_place": {q: float(np.sqrt(np.mean(c[p == q] ** 2))) for q in places_},
        "along_median_abs_px_by_place": {q: float(np.median(np.abs(a[p == q]))) for q in places_},
        "across_median_abs_px_by_place": {q: float(np.median(np.abs(c[p == q]))) for q in places_},
        "observations_by_place": {q: int((p == q).sum()) for q in places_},
        "along_motion_px_by_sector": {f"{-180 + 45 * k:+d}..{-135 + 45 * k:+d}": float(a[sectors == k].mean())
                                      for k in range(8) if (sectors == k).any()},
        "along_motion_px_by_colatitude": by_colatitude,  # band -> place group -> (mean, observations)
    }


def measure(root: Path, parts: list[str], overrides: list[str], noise_px: float = 0.3,
            pipes: list[str] | None = None, turn_reach: int = 25, turn_deg: float = 2.0) -> dict:
    dataset = load_dataset(root)
    settings = load_settings(None, overrides)
    network = load_network(root / "ground_truth" / "network.yaml")
    front = track_and_classify(dataset, settings)
    gt = read_tum(root / "ground_truth" / "poses.tum")
    ts = np.asarray(gt.timestamps)
    idx = [int(np.argmin(np.abs(ts - k.timestamp))) for k in front.keyframes]
    R, C = gt.rotations[idx], gt.positions[idx]
    exact, pipe_of = exact_observations_on_pipes(front, dataset.camera, network, R, C)
    on = [None] * len(exact) if not pipes else [np.isin(p, pipes) for p in pipe_of]
    motions, places = motion_and_place(front, exact)
    errors = errors_by_place_and_sector(front, dataset.camera, exact, motions, places)
    errors["along_motion_px_by_turn"] = errors_by_turn(front, exact, motions, places, R)
    errors["frame_rotation"] = frame_rotations(front, dataset.camera, exact, places, R)
    if pipes:  # the same figures for the chosen pipes' tracks alone
        errors["on_pipes"] = errors_by_place_and_sector(
            front, dataset.camera, [np.where(o[:, None], uv, np.nan) for uv, o in zip(exact, on)], motions, places)
    tracked = list(front.keyframes)
    out = {"dataset": root.name, "keyframes": len(tracked),
           "exact_share": float(np.mean(np.concatenate([np.all(np.isfinite(u), axis=1) for u in exact]))),
           **errors, "parts": {}}
    colatitudes = [colatitude_deg(dataset.camera, np.nan_to_num(uv)) for uv in exact]  # the same for every part
    for part in parts:
        kfs = []
        if part.startswith("debiased"):
            lags = mean_lag(front, dataset.camera, exact, motions, places, part.partition("-")[2])
            pixels = [kf.keypoints - lag for kf, lag in zip(tracked, lags)]
        elif part == "noise":
            pixels = noisy(tracked, exact, noise_px, np.random.default_rng(0))
        elif part == "turns-exact":
            near = near_turns(R, turn_reach, turn_deg)
            pixels = [np.where((near[k] & np.all(np.isfinite(uv), axis=1))[:, None], uv, kf.keypoints)
                      for k, (kf, uv) in enumerate(zip(tracked, exact))]
        else:
            pixels = [part_pixels(part, kf.keypoints, uv, m, q, dataset.camera.height / 2, col, o)
                      for kf, uv, m, q, col, o in zip(tracked, exact, motions, places, colatitudes, on)]
        for kf, px in zip(tracked, pixels):
            bearings, _ = dataset.camera.unproject(px)
            kfs.append(replace(kf, keypoints=px, bearings=bearings.reshape(-1, 3)))
        front.keyframes[:] = kfs
        t = time.perf_counter()
        out["parts"][part] = dict(judged(map_network(front, dataset, settings), C, network),
                                  seconds=time.perf_counter() - t)
        print(f"{root.name} {part:<7s} " + ", ".join(f"{k} {_fmt(v)}" for k, v in out["parts"][part].items()),
              flush=True)
    front.keyframes[:] = tracked
    return out


def _fmt(v) -> str:
    if isinstance(v, list):
        return "[" + " ".join(x if isinstance(x, str) else f"{x:+.3f}" for x in v) + "]"
    return f"{v:.5g}" if isinstance(v, float) else str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("datasets", nargs="+")
    ap.add_argument("--parts", nargs="+", default=["all", "exact", "along", "across"], choices=PARTS)
    ap.add_argument("--noise-px", type=float, default=0.3, help="sigma of the noise part's Gaussian noise (px)")
    ap.add_argument("--turn-reach", type=int, default=25, help="turns-exact: keyframes either side of a turning one")
    ap.add_argument("--turn-deg", type=float, default=2.0, help="turns-exact: a keyframe turns when it turns this "
                    "far (deg) from the one before")
    ap.add_argument("--on", nargs="+", default=None, metavar="SEGMENT",
                    help="the pixel parts add their error only to tracks whose point lies on these segments of "
                         "ground_truth/network.yaml (an arc by its id)")
    ap.add_argument("--set", action="append", default=[], help="settings override section.key=value (repeatable)")
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "exact_observations.json"))
    args = ap.parse_args()
    results = []
    for root in args.datasets:
        r = measure(Path(root), args.parts, args.set, args.noise_px, args.on, args.turn_reach, args.turn_deg)
        r["overrides"] = args.set
        print(f"{r['dataset']}: {r['keyframes']} keyframes, {100 * r['exact_share']:.1f} % of the observations "
              "with an exact projection; tracked error (px) by place in the track")
        for key in ("observations", "along_motion_px", "along_rms_px", "along_median_abs_px", "across_motion_px",
                    "across_rms_px", "across_median_abs_px"):
            cells = (f"{p}: {v:+.4f}" if isinstance(v, float) else f"{p}: {v}" for p, v in r[f"{key}_by_place"].items())
            print(f"   {key.replace('_px', ''):<17s}" + " ".join(cells))
        print("   along the motion by sector (deg, y down): " + " ".join(
            f"{s}: {v:+.4f}" for s, v in r["along_motion_px_by_sector"].items()))
        print("   along the motion by colatitude (deg), places " + ", ".join(f"{a}-{b}" for a, b in _PLACE_GROUPS)
              + ": mean (observations)")
        for band, cells in r["along_motion_px_by_colatitude"].items():
            print(f"     {band:>8s}: " + "  ".join(f"{g} {v:+.4f} ({n})" for g, (v, n) in cells.items()))
        print("   along the motion by the keyframe's true turn from the one before (deg), places 1-6: mean "
              "(observations)")
        for band, cells in r["along_motion_px_by_turn"].items():
            print(f"     {band:>8s}: {cells['keyframes']} keyframes  " + "  ".join(
                f"{q} {c[0]:+.4f} ({c[1]})" for q, c in cells.items() if q != "keyframes"))
        print("   the rotation the young tracks' error implies per keyframe (deg, camera x y z):")
        for band, cells in r["frame_rotation"].items():
            if band != "turns":
                print(f"     turn {band:>9s}: {cells['keyframes']} keyframes, mean {cells['mean_deg']}, std "
                      f"{cells['std_deg']}")
        for t in r["frame_rotation"].get("turns", []):
            print(f"     keyframes {t['keyframes'][0]}-{t['keyframes'][1]} (true turn {t['true_turn_deg']} deg): "
                  f"summed {t['sum_deg']}")
        if "on_pipes" in r:
            print(f"   the tracks on {' '.join(args.on)} alone, by place in the track:")
            for key in ("observations", "along_motion_px", "along_rms_px", "across_motion_px", "across_rms_px"):
                cells = (f"{p}: {v:+.4f}" if isinstance(v, float) else f"{p}: {v}"
                         for p, v in r["on_pipes"][f"{key}_by_place"].items())
                print(f"   {key.replace('_px', ''):<17s}" + " ".join(cells))
        results.append(r)
    summary = {"benchmark": "exact_observations", "machine": platform.platform(), "cpus": os.cpu_count(),
               "results": results}
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
