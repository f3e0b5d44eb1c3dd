"""Straight-section metric VO (fisheye paper III-C) on fisheye-straight renders, without any scale alignment.

    python benchmarks/bench_straight.py [--frames 400] [--width 640 --height 480] [--spacing 0.01]
                                        [--data /tmp/pipemap-bench] [--seed 0]

Renders the preset (cached under --data), tracks it once, then runs the straight VO with the paper's
settings (tau = 2.5e5) and with tau = 0 (the scale then comes only from the first window's free-radius
rescale), writes both result folders and evaluates them: distance travelled (first -> last keyframe
along the true axis), path length, ATE RMSE after a rigid (no scale) and a Sim(3) alignment. Also times
one window solve at the budget size (100 keyframes, ~10k points, ~50k observations; synthetic) and
lists the real windows' sizes and times. Prints a summary and writes benchmarks/results/straight.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path

import numpy as np


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "backend"))
from pipemap.backend import BundleProblem, Observations
from pipemap.config import load_settings
from pipemap.dataset import load_dataset
from pipemap.evaluation import evaluate
from pipemap.frontend import track_frames
from pipemap.geometry.cylinder import fit_cylinder
from pipemap.output import result_folder
from pipemap.frontend.classification import SequenceClass
from pipemap.pipeline import FrontEndResult, map_network, write_results
from pipemap.sim.simulate import simulate
from pipe_window import RADIUS, make_pipe_window  # the tests' synthetic window


def dataset(args) -> Path:
    name = f"fisheye-straight-{args.width}x{args.height}-{args.frames}-{args.spacing}-s{args.seed}"
    root = Path(args.data) / name
    if not (root / "dataset.yaml").exists():
        shutil.rmtree(root, ignore_errors=True)
        root.parent.mkdir(parents=True, exist_ok=True)
        simulate("fisheye-straight", root, width=args.width, height=args.height, frames=args.frames, seed=args.seed,
                 spacing_m=args.spacing)
    return root


def run_case(ds, keyframes, frontend_s, overrides, out: Path) -> dict:
    settings = load_settings(overrides=overrides)
    t = time.perf_counter()
    n = len(ds)
    # A straight pipe: every frame straight (the classification is measured by bench_classification).
    straight = np.zeros(n, bool)
    front = FrontEndResult(keyframes, SequenceClass(np.arange(n), np.zeros(n), straight, straight), n,
                           {"frontend": frontend_s})
    net = map_network(front, ds, settings)
    res = net.straight
    seconds = {"frontend": frontend_s, "straight_relative": res.seconds["relative"],
               "straight_windows": res.seconds["windows"], "straight_total": time.perf_counter() - t}
    shutil.rmtree(out, ignore_errors=True)
    with result_folder(out) as tmp:
        write_results(tmp, ds, front, net, settings, seconds)
    m = evaluate(out, ds.root)
    fwd = m.distance.forward
    return {
        "overrides": overrides,
        "result": str(out),
        "keyframes": len(res.indices),
        "points": len(res.points),
        "distance_gt_m": fwd.ground_truth,
        "distance_est_m": fwd.estimate,
        "distance_error_pct": 100 * (fwd.estimate - fwd.ground_truth) / fwd.ground_truth,
        "path_length_error_pct": m.path_length_error_pct,
        "ate_rigid_mm": 1000 * m.ate_rigid.rmse,
        "ate_rigid_pct_of_path": m.ate_rmse_pct(m.ate_rigid),
        "ate_sim3_mm": 1000 * m.ate_sim3.rmse,
        "seconds": {k: round(v, 3) for k, v in seconds.items()},
        "windows": [w.to_dict() for w in res.windows],
    }


def budget_window(seed: int = 0) -> dict:
    """One window at the budget size, solved as the VO does: cylinder fit, then SBA with the first pose held."""
    w = make_pipe_window(n_frames=100, n_points=10400, seed=seed)
    obs = Observations(w.obs_camera, w.obs_point, w.obs_pixels)
    t = time.perf_counter()
    fit = fit_cylinder(w.points0, RADIUS, reference=(w.R0[0], w.t0[0]), direction=w.t0[-1] - w.t0[0])
    fit_s = time.perf_counter() - t
    res = BundleProblem.from_settings(w.camera, (w.R0, w.t0), w.points0, obs, load_settings(), cylinder=fit,
                                      cylinder_points=fit.inliers).solve()
    true = np.linalg.norm(w.t[-1] - w.t[0])
    est = np.linalg.norm(res.poses[-1, :3, 3] - res.poses[0, :3, 3])
    return {"keyframes": 100, "points": len(w.points), "observations": len(obs), "fit_s": round(fit_s, 3),
            "solve_s": round(res.time_s, 3), "iterations": res.iterations, "rms_px": res.rms_px,
            "distance_error_pct": 100 * (est - true) / true}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--spacing", type=float, default=0.01, help="metres between frames")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data", default="/tmp/pipemap-bench", help="where renders and result folders are kept")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "straight.json"))
    args = ap.parse_args()

    root = dataset(args)
    ds = load_dataset(root)
    settings = load_settings()
    t = time.perf_counter()
    keyframes = list(track_frames(ds.frames(), ds.camera, settings.frontend, settings.seed))
    frontend_s = time.perf_counter() - t
    base = Path(args.data) / (root.name + "-results")
    cases = {
        "tau_2.5e5": run_case(ds, keyframes, frontend_s, [], base / "tau"),
        "tau_0": run_case(ds, keyframes, frontend_s, ["bundle.tau=0"], base / "tau0"),
    }
    report = {
        "benchmark": "straight-section VO (fisheye paper III-C), no scale alignment",
        "dataset": {"preset": "fisheye-straight", "frames": args.frames, "width": args.width, "height": args.height,
                    "spacing_m": args.spacing, "seed": args.seed,
                    "lost_keyframes": sum(not k.pose_valid for k in keyframes[1:])},
        "frontend_s": round(frontend_s, 2),
        "cases": cases,
        "budget_window": budget_window(),
        "machine": {"cpus": os.cpu_count(), "load": os.getloadavg(), "python": platform.python_version()},
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2, default=float) + "\n")
    print(f"fisheye-straight {args.width}x{args.height}, {args.frames} frames {args.spacing} m apart, "
          f"{len(keyframes)} keyframes, front end {frontend_s:.1f} s")
    for name, c in cases.items():
        print(f"  {name:10s} distance {c['distance_est_m']:.4f} / {c['distance_gt_m']:.4f} m "
              f"({c['distance_error_pct']:+.3f} %), ATE rigid {c['ate_rigid_mm']:.2f} mm "
              f"({c['ate_rigid_pct_of_path']:.3f} % of path), Sim(3) {c['ate_sim3_mm']:.2f} mm, "
              f"windows {c['seconds']['straight_windows']:.1f} s")
        for w in c["windows"]:
            print(f"      window {w['first']:4d}-{w['last']:4d}: {w['points']} points, {w['observations']} obs, "
                  f"{w['time_s']:.2f} s, {w['rms_px']:.3f} px")
    b = report["budget_window"]
    print(f"  budget window: {b['keyframes']} keyframes, {b['points']} points, {b['observations']} obs: "
          f"solve {b['solve_s']:.2f} s ({b['iterations']} iterations), fit {b['fit_s']:.2f} s")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
