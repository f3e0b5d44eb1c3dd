"""Where along a track lossy video biases its observations (the image-conditions issue: H.264 footage maps short).

    python benchmarks/bench_track_bias.py DATASET [DATASET ...] [--shift-px 0.05]

For each dataset folder (a simulated one: its ground_truth/poses.tum and network.yaml are read) it runs the
network pipeline's front end and triangulates every track seen in 4 or more keyframes from the TRUE keyframe
poses, so that only the observations are judged:
- the radius of those points against the true pipe radius, from all observations and with each track's first
  one (where its anchor patch was cut) left out: image motion measured short puts the points too far out;
- each observation's offset along the track's image motion from the reprojection of the point triangulated
  without the first observation, by its place in the track (0 = first): + = ahead of the motion.
With --shift-px it also runs the back end (as `pipemap run` does) on the keyframes as tracked and with every
track's first observation moved that far back along its motion, and prints the distance travelled forward
(start to the farthest keyframe) and back against the truth: how much of the shortfall the first observations
carry. Writes benchmarks/results/track_bias.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipemap.backend.triangulate import triangulate_rays
from pipemap.config import Settings
from pipemap.dataset import load_dataset
from pipemap.network import load_network
from pipemap.pipeline import map_network, track_and_classify
from pipemap.trajectory import read_tum

MIN_OBS = 4
PLACES = 7


def true_poses(root: Path, keyframes) -> tuple[np.ndarray, np.ndarray]:
    gt = read_tum(root / "ground_truth" / "poses.tum")
    i = [int(np.argmin(np.abs(gt.timestamps - k.timestamp))) for k in keyframes]
    return gt.rotations[i], gt.positions[i]


def observations(keyframes):
    """(keyframe, row, track id, place in the track, track length) of every observation, by track then keyframe."""
    k = np.concatenate([np.full(len(kf), n) for n, kf in enumerate(keyframes)])
    row = np.concatenate([np.arange(len(kf)) for kf in keyframes])
    tid = np.concatenate([kf.track_ids for kf in keyframes])
    o = np.lexsort((k, tid))
    k, row, tid = k[o], row[o], tid[o]
    _, start, counts = np.unique(tid, return_index=True, return_counts=True)
    place = np.arange(len(tid)) - np.repeat(start, counts)
    return k, row, tid, place, np.repeat(counts, counts)


def triangulated(keyframes, R, C, obs, use):
    k, row, tid = obs[0][use], obs[1][use], obs[2][use]
    uniq, inv = np.unique(tid, return_inverse=True)
    rays = np.stack([keyframes[a].bearings[b] @ R[a].T for a, b in zip(k, row)])
    tri = triangulate_rays(C[k], rays, inv, len(uniq), min_parallax_deg=2.0)
    good = tri.valid & (tri.max_error_deg < 1.0)
    return uniq[good], tri.points[good]


def radius_bias_pct(points: np.ndarray, network) -> float:
    """Median distance of the points from the true axis against the radius (%), away from the pipe's ends."""
    d = np.full(len(points), np.inf)
    inside = np.zeros(len(points), bool)
    for s in network.straight_pieces():
        v = points - s.start
        h = v @ s.axis
        d = np.minimum(d, np.linalg.norm(v - np.clip(h, 0, s.length)[:, None] * s.axis, axis=1))
        inside |= (h > 0.3) & (h < s.length - 0.3)
    return float(100.0 * (np.median(d[inside]) / network.radius_m - 1.0))


def offsets_by_place(keyframes, camera, R, C, obs, tids, X) -> dict[int, float]:
    k, row, tid, place, length = obs
    at = np.searchsorted(tids, tid).clip(0, max(len(tids) - 1, 0))
    use = (tids[at] == tid) & (length >= MIN_OBS) & (place < PLACES)
    px = np.stack([keyframes[a].keypoints[b] for a, b in zip(k, row)])
    nxt = np.where(place + 1 < length, np.arange(len(k)) + 1, np.arange(len(k)) - 1)
    motion = np.where((nxt > np.arange(len(k)))[:, None], px[nxt] - px, px - px[nxt])
    motion /= np.maximum(np.linalg.norm(motion, axis=1, keepdims=True), 1e-9)
    i = np.flatnonzero(use)
    local = np.einsum("nji,nj->ni", R[k[i]], X[at[i]] - C[k[i]])
    proj, ok = camera.project(local)
    off = np.einsum("ni,ni->n", px[i] - proj.reshape(-1, 2), motion[i])
    return {int(p): float(off[ok.reshape(-1) & (place[i] == p)].mean()) for p in range(PLACES)}


def distances_pct(front, dataset, R, C) -> tuple[float, float]:
    P = map_network(front, dataset, Settings()).map.poses[:, :3, 3]
    far = int(np.argmax(np.linalg.norm(C - C[0], axis=1)))

    def pct(a, b):
        return float(100.0 * (np.linalg.norm(P[b] - P[a]) / np.linalg.norm(C[b] - C[a]) - 1.0))
    return pct(0, far), pct(far, len(C) - 1)


def first_moved_back(front, camera, obs, px: float):
    k, row, tid, place, length = obs
    first = np.flatnonzero((place == 0) & (length >= 2))
    moved = [kf.keypoints.copy() for kf in front.keyframes]
    for i in first:
        a, b, c, d = k[i], row[i], k[i + 1], row[i + 1]
        m = front.keyframes[c].keypoints[d] - front.keyframes[a].keypoints[b]
        moved[a][b] -= px * m / max(np.linalg.norm(m), 1e-9)
    keyframes = [replace(kf, keypoints=p, bearings=camera.unproject(p)[0].reshape(-1, 3))
                 for kf, p in zip(front.keyframes, moved)]
    return replace(front, keyframes=keyframes)


def measure(root: Path, shift_px: float) -> dict:
    dataset = load_dataset(root)
    network = load_network(root / "ground_truth" / "network.yaml")
    front = track_and_classify(dataset, Settings())
    kfs = front.keyframes
    R, C = true_poses(root, kfs)
    obs = observations(kfs)
    long_enough = obs[4] >= MIN_OBS
    tids, X = triangulated(kfs, R, C, obs, long_enough & (obs[3] >= 1))
    out = {"dataset": str(root), "keyframes": len(kfs),
           "radius_bias_pct": radius_bias_pct(triangulated(kfs, R, C, obs, long_enough)[1], network),
           "radius_bias_without_first_pct": radius_bias_pct(X, network),
           "offset_along_motion_px": offsets_by_place(kfs, dataset.camera, R, C, obs, tids, X)}
    if shift_px > 0:
        out["distance_pct"] = distances_pct(front, dataset, R, C)
        out["distance_first_moved_back_pct"] = distances_pct(first_moved_back(front, dataset.camera, obs, shift_px),
                                                              dataset, R, C)
        out["shift_px"] = shift_px
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("datasets", nargs="+")
    ap.add_argument("--shift-px", type=float, default=0.0, help="also run the back end with every track's first "
                    "observation moved this far back along its motion")
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "track_bias.json"))
    args = ap.parse_args()
    results = []
    for root in args.datasets:
        r = measure(Path(root), args.shift_px)
        results.append(r)
        print(f"{Path(root).name}: {r['keyframes']} keyframes; true-pose points' radius {r['radius_bias_pct']:+.3f} %, "
              f"without each track's first observation {r['radius_bias_without_first_pct']:+.3f} %")
        print("   offset along the motion by place in the track (px): "
              + " ".join(f"{p}: {v:+.4f}" for p, v in r["offset_along_motion_px"].items()))
        if "distance_pct" in r:
            (f, b), (f2, b2) = r["distance_pct"], r["distance_first_moved_back_pct"]
            print(f"   distance forward {f:+.3f} %, back {b:+.3f} %; first observations {args.shift_px:g} px back: "
                  f"forward {f2:+.3f} %, back {b2:+.3f} %")
    summary = {"benchmark": "track_bias", "machine": platform.platform(), "cpus": os.cpu_count(), "results": results}
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
