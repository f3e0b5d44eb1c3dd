"""Sliding-window SBA with the cylinder prior at the size of one window: 100 keyframes, ~10k wall points,
~50k observations (0.5 px noise, 5 % gross outliers), started at 0.9 x the true scale.

    python benchmarks/bench_bundle.py [--seeds 3] [--points 10400]

Measures the solve time (and the initial cylinder fit), accuracy against ground truth (distance
travelled, position RMSE without alignment, rotation error, outlier recall) and the same window
solved without the cylinder (tau = 0), whose scale stays wrong. Prints a table and writes
benchmarks/results/bundle.json, with the conditions (CPU count, load average, BLAS threading).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "backend"))
from pipemap.backend import BundleProblem, Observations
import pipe_window as scene  # the tests' synthetic window
from pipemap.geometry.cylinder import fit_cylinder
from pipemap.geometry.rotations import log_so3



def observations_of(w) -> Observations:
    return Observations(w.obs_camera, w.obs_point, w.obs_pixels)


def _blas_threads() -> str:
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return f"threadpoolctl not installed (OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')})"
    return "; ".join(f"{i['internal_api']} x{i['num_threads']} (held to 1 during solve)" for i in threadpool_info()
                     if i.get("user_api") == "blas")


def accuracy(w, res) -> dict:
    t_est = res.poses[:, :3, 3]
    length = lambda t: float(np.linalg.norm(np.diff(t, axis=0), axis=1).sum())  # noqa: E731
    end = lambda t: float(np.linalg.norm(t[-1] - t[0]))  # noqa: E731
    rot = np.degrees(np.linalg.norm(log_so3(np.swapaxes(res.poses[:, :3, :3], 1, 2) @ w.R), axis=1))
    flagged = ~res.inliers
    return {
        "distance_travelled_error_pct": 100 * (length(t_est) / length(w.t) - 1),
        "end_to_end_error_pct": 100 * (end(t_est) / end(w.t) - 1),
        "position_rmse_mm": 1000 * float(np.sqrt(np.mean(np.sum((t_est - w.t) ** 2, axis=1)))),
        "rotation_error_max_deg": float(rot.max()),
        "outlier_recall": float(flagged[w.outlier].mean()),
        "inliers_rejected_frac": float(flagged[~w.outlier].mean()),
        "rms_px": res.rms_px,
        "iterations": res.iterations,
        "solve_s": res.time_s,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--points", type=int, default=10400, help="wall points drawn (those seen twice are kept)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bundle.json")
    args = ap.parse_args()
    report = {
        "conditions": {"cpus": os.cpu_count(), "load_average_at_start": list(os.getloadavg()),
                       "blas": _blas_threads(), "python": platform.python_version(), "numpy": np.__version__},
        "scene": {"keyframes": args.frames, "radius_m": scene.RADIUS, "step_m": 0.01, "noise_px": 0.5,
                  "outlier_frac": 0.05, "initial_scale": 0.9, "camera": "190 deg polynomial, 640x480"},
        "runs": [],
    }
    print(f"{'seed':>4s} {'pts':>6s} {'obs':>6s} {'fit s':>6s} {'solve s':>7s} {'it':>3s} {'dist %':>8s} "
          f"{'pos mm':>7s} {'rot deg':>7s} {'recall':>6s} | {'tau=0 dist %':>12s} {'s':>5s}")
    for seed in range(args.seeds):
        w = scene.make_pipe_window(n_frames=args.frames, n_points=args.points, seed=seed)
        t0 = time.perf_counter()
        fit = fit_cylinder(w.points0, scene.RADIUS, reference=(w.R0[0], w.t0[0]))
        fit_s = time.perf_counter() - t0
        res = BundleProblem(w.camera, (w.R0, w.t0), w.points0, observations_of(w), cylinder=fit, huber_px=1.0).solve()
        free = BundleProblem(w.camera, (w.R0, w.t0), w.points0, observations_of(w), tau=0.0, huber_px=1.0).solve()
        a, b = accuracy(w, res), accuracy(w, free)
        run = {"seed": seed, "points": len(w.points), "observations": len(observations_of(w)), "cylinder_fit_s": fit_s,
               "cylinder_fit_free_radius_m": fit.free_radius, "with_cylinder": a, "tau_zero": b}
        report["runs"].append(run)
        print(f"{seed:4d} {len(w.points):6d} {len(observations_of(w)):6d} {fit_s:6.3f} {a['solve_s']:7.2f} "
              f"{a['iterations']:3d} {a['distance_travelled_error_pct']:8.4f} {a['position_rmse_mm']:7.3f} "
              f"{a['rotation_error_max_deg']:7.3f} {a['outlier_recall']:6.3f} | "
              f"{b['distance_travelled_error_pct']:12.3f} {b['solve_s']:5.2f}")
    times = [r["with_cylinder"]["solve_s"] for r in report["runs"]]
    report["summary"] = {"solve_s_median": float(np.median(times)), "solve_s_max": float(np.max(times)),
                         "budget_s": 2.0,
                         "distance_travelled_error_pct_max_abs":
                             max(abs(r["with_cylinder"]["distance_travelled_error_pct"]) for r in report["runs"]),
                         "position_rmse_mm_max": max(r["with_cylinder"]["position_rmse_mm"] for r in report["runs"])}
    print(f"solve time median {report['summary']['solve_s_median']:.2f} s, "
          f"max {report['summary']['solve_s_max']:.2f} s (budget 2 s); {report['conditions']['cpus']} CPUs, "
          f"load {report['conditions']['load_average_at_start'][0]:.1f}; BLAS: {report['conditions']['blas']}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
