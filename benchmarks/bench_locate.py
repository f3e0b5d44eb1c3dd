"""`pipemap locate` against the simulator's ground truth: chainage and clock of random wall pixels.

    python benchmarks/bench_locate.py RESULT DATASET [--pixels 200] [--seed 0] [--name paper-loop]

For random frames (keyframes and the frames between them) and random pixels in the appearance map's
colatitude band (the periphery where the map is made; pixels nearer the optical axis see the wall down the
pipe at grazing angles), the true wall point is cast exactly from the true pose into the simulator's scene,
and its true chainage and clock are taken on the true route: the visited straight segments of
ground_truth/network.yaml in the order the true camera passes them, joined as the estimate's route is (arcs
at elbows), 12 o'clock = world +z, from the true position of the first keyframe. Like the estimate's, a point's
coordinates are those along the pipe whose wall it lies on (the piece the true ray met): its route segment,
or for a tee's stub, which the route never enters, the segment of the through pipe it continues. Acceptance:
chainage error <= 0.1 % of chainage + 5 mm and clock error <= 3 deg. Also the share of errors within two
of the reported sigmas. Prints and writes benchmarks/results/locate_<name>.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import yaml

from pipemap.config import AppearanceSettings
from pipemap.dataset import load_dataset
from pipemap.inspection.locate import locate_pixels, open_result
from pipemap.evaluation.locate_truth import segment_of_piece, true_route
from pipemap.mapping.appearance import colatitude_band
from pipemap.sim.presets import get_setup
from pipemap.sim.raycast import RayCaster

RESULTS = Path(__file__).parent / "results"


def measure(result: Path, dataset: Path, pixels: int, seed: int) -> dict:
    ds = load_dataset(dataset)
    sim = yaml.safe_load((dataset / "ground_truth" / "simulation.yaml").read_text())
    scene = get_setup(sim["preset"], ds.camera.width, ds.camera.height, sim.get("route"), sim["seed"]).scene
    caster = RayCaster(scene, dtype=np.float64)
    gt = ds.ground_truth_poses()
    res = open_result(result)
    k0, k1 = res.keyframe_frames[0], res.keyframe_frames[-1]
    route = true_route(ds.network(), gt.positions, gt.positions[k0], gt.positions[k1])
    gt_chain = route.follow(gt.positions)
    piece_ids = [p.id for p in scene.pieces]
    piece_segment = segment_of_piece(route, ds.network(), piece_ids)
    lo, hi = np.radians(colatitude_band(AppearanceSettings(), ds.camera))
    rng = np.random.default_rng(seed)
    rows = []
    t0 = time.perf_counter()
    while len(rows) < pixels:
        frame = int(rng.integers(k0, k1 + 1))
        uv = rng.uniform([0, 0], [ds.camera.width - 1, ds.camera.height - 1], size=(8, 2))
        bearings, valid = ds.camera.unproject(uv)
        theta = np.arccos(np.clip(bearings[:, 2], -1, 1))
        keep = valid & (theta > lo) & (theta < hi)
        uv, bearings = uv[keep], bearings[keep]
        if not len(uv):
            continue
        hits = caster.cast(gt.rotations[frame], gt.positions[frame], bearings)
        uv = uv[hits.hit & ~hits.cap]
        if not len(uv):
            continue
        b, _ = ds.camera.unproject(uv)
        hits = caster.cast(gt.rotations[frame], gt.positions[frame], b)
        truth = gt.positions[frame] + hits.t[:, None] * (b @ gt.rotations[frame].T)
        names = [piece_segment.get(piece_ids[k], "") for k in hits.pipe]
        tc, tk, _, _ = route.to_route(truth, wall=True, near_chainage=gt_chain[frame],
                                      segment=route.segments_named(names, gt_chain[frame]))
        est = locate_pixels(res, frame, uv)
        for i in range(len(uv)):
            rows.append(dict(frame=frame, keyframe=est.pose == "keyframe", truth_chainage=tc[i], truth_clock=tk[i],
                             chainage=est.chainage[i], clock=est.clock_deg[i], sigma_chainage=est.sigma_chainage[i],
                             sigma_clock=est.sigma_clock_deg[i]))
    rows = rows[:pixels]
    return summarise(rows, time.perf_counter() - t0)


def summarise(rows: list[dict], seconds: float) -> dict:
    tc = np.array([r["truth_chainage"] for r in rows])
    c = np.array([r["chainage"] for r in rows])
    dk = np.abs((np.array([r["clock"] for r in rows]) - [r["truth_clock"] for r in rows] + 180) % 360 - 180)
    dc = np.abs(c - tc)
    located = np.isfinite(c)
    allowed = 0.001 * np.abs(tc) + 0.005
    ok = located & (dc <= allowed) & (dk <= 3.0)
    key = np.array([r["keyframe"] for r in rows])
    sc = np.array([r["sigma_chainage"] for r in rows])
    sk = np.array([r["sigma_clock"] for r in rows])

    def stats(x, m):
        x = x[m & located]
        return {"median": round(float(np.median(x)), 5), "p95": round(float(np.percentile(x, 95)), 5),
                "max": round(float(x.max()), 5)} if len(x) else None

    return {"pixels": len(rows), "located": int(located.sum()), "within_acceptance": int(ok.sum()),
            "chainage_error_m": stats(dc, np.ones_like(key)), "clock_error_deg": stats(dk, np.ones_like(key)),
            "chainage_error_m_keyframes": stats(dc, key), "chainage_error_m_between": stats(dc, ~key),
            "clock_error_deg_keyframes": stats(dk, key), "clock_error_deg_between": stats(dk, ~key),
            "keyframe_pixels": int(key.sum()), "route_length_m": round(float(np.nanmax(tc)), 3),
            "within_2_sigma": {"chainage": round(float(np.mean(dc[located] <= 2 * sc[located])), 3),
                               "clock": round(float(np.mean(dk[located] <= 2 * sk[located])), 3)},
            "worst_allowed_ratio": round(float(np.nanmax(dc / allowed)), 3), "seconds": round(seconds, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("result", type=Path)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--pixels", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--name", default="scene")
    args = ap.parse_args()
    out = measure(args.result, args.dataset, args.pixels, args.seed)
    out.update(result=str(args.result), dataset=str(args.dataset), seed=args.seed)
    print(json.dumps(out, indent=2))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"locate_{args.name}.json").write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
