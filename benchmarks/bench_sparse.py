"""Sparse cylinder-constrained VO (2010 report section 5): a replica of Table 2 on the report's pipes, rendered.

    python benchmarks/bench_sparse.py [--data /tmp/pipemap-bench-dense] [--spacing-6in 0] [--spacing-16in 0]
                                      [--seed 1]
                                      [--cases 6in-forward,6in-forward-reverse,16in-forward-reverse,16in-forward]
                                      [--measured-offset] [--set section.key=value ...]

Renders (cached under --data, shared with bench_dense.py) paper-straight-6in forward and
forward-reverse and paper-straight-16in forward-reverse and forward at the presets' full image
sizes. A spacing of 0 (the default) keeps the preset's own frame spacing, i.e. the report's frame
counts (6in: 4256 forward, 3369 forward & reverse; 16in: 2392 forward & reverse); a positive
spacing renders fewer, wider-spaced frames. Every dataset gets the gain mask of its camera
(report section 3.2: the white-card preset of that robot).

sparse-cylinder runs on every case with its default settings: no camera offset is given, the
method estimates it (the initial batch, 5.3.2; where that batch says the images cannot determine it,
as with the 16-inch pipe's 25 deg lens, again over offset_long_keyframes keyframes: "long batch" in
the table), and no scale is aligned. With --measured-offset the
run is given the camera's offset from the axis as the report's authors measured theirs by hand
(eq. 45): the first true camera centre rounded to the millimetre, flagged as measured, so that the
batch keeps it where it cannot determine the offset itself (run.json says which happened). --set
passes further settings overrides. Each result folder is judged by
pipemap.evaluation.evaluate (distance travelled along the pipe, eqs. 50-51); the estimated offset
is compared with the simulator's mount (offset_down_m below the axis). Prints the table and writes
benchmarks/results/sparse.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import time
from pathlib import Path

import numpy as np

from straight_pipes import CASES, dataset, distance_rows, distance_text

from pipemap.config import load_settings
from pipemap.dataset import load_dataset
from pipemap.evaluation import evaluate
from pipemap.straight.sparse.run import run_sparse

REPORT = {  # Table 2 of the 2010 report, sparse column: abs error %
    "6in-forward": {"forward": 0.306, "note": "dataset 1 (dataset 2: 0.289)"},
    "6in-forward-reverse": {"forward": 0.128, "reverse": 0.060, "total": 0.034},
    "16in-forward-reverse": {"forward": 0.21, "reverse": 0.61, "total": 0.201},
    "16in-forward": {"forward": 0.21, "note": "the forward leg of pipe 2's forward & reverse dataset"},
}


def true_offset(root: Path) -> list[float]:
    """The first camera's (C_X, C_Y) in the report's pipe frame: camera y and z offsets from the axis
    (the simulated pipes lie along world x with the axis at y = z = 0)."""
    gt = load_dataset(root).ground_truth_poses()
    return [float(gt.positions[0, 1]), float(gt.positions[0, 2])]


def _sigma_text(fraction: float | None) -> str:
    """The kept offset's sigma, a fraction of the wall distance (none for eqs. 45-49 or a measured offset)."""
    return "" if fraction is None else f", sigma {100 * fraction:.2f} %"


def run_case(args, case: str, root: Path) -> dict:
    out = Path(args.data) / "results" / f"{root.name}-sparse-cylinder"
    shutil.rmtree(out, ignore_errors=True)
    t = time.perf_counter()
    overrides = list(args.set)
    if args.measured_offset:
        given = [round(x, 3) for x in true_offset(root)]
        overrides += [f"sparse.initial_offset_m={given}", "sparse.offset_measured=true"]
    settings = load_settings(None, overrides)
    res = run_sparse(root, out, settings)
    run = json.loads((out / "run.json").read_text())
    wall = time.perf_counter() - t
    d = evaluate(out, root).distance
    truth = true_offset(root)
    entry = {
        "case": case, "dataset": root.name, "method": "sparse-cylinder", "frames": res.frames,
        "keyframes": len(res.indices), "gain_corrected": load_dataset(root).has_gain_mask,
        "offset_mm": {"C_X": round(res.offset[0] * 1e3, 3), "C_Y": round(res.offset[1] * 1e3, 3),
                      "true_C_X": round(truth[0] * 1e3, 3), "true_C_Y": round(truth[1] * 1e3, 3),
                      "batch_rms_px": round(float(res.offset_rms_px), 3),
                      "batch_sigma_mm": None if run["camera_offset_m"].get("batch_sigma_m") is None else
                      [round(x * 1e3, 3) for x in run["camera_offset_m"]["batch_sigma_m"]],
                      "source": run["camera_offset_m"].get("source"),
                      "sigma_fraction": run["camera_offset_m"].get("sigma_fraction"),
                      "estimates": run["camera_offset_m"].get("estimates")},
        "overrides": overrides, "refinement_dof": run.get("refinement_dof"),
        "rating": run.get("quality", {}).get("rating"),
        "frames_per_second": round(res.frames / (res.seconds["features"] + res.seconds["motion"]), 2),
        "seconds": {k: round(v, 1) for k, v in res.seconds.items()} | {"wall": round(wall, 1)},
        **distance_rows(d), "report_abs_error_pct": REPORT[case],
    }
    print(f"{case:21s} {distance_text(d)}  C_Y {res.offset[1] * 1e3:6.2f} mm (true {truth[1] * 1e3:6.2f})"
          f" [{entry['offset_mm']['source']}{_sigma_text(entry['offset_mm']['sigma_fraction'])}] {entry['rating']}"
          f"  {entry['frames_per_second']:5.1f} frames/s", flush=True)
    return entry


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="/tmp/pipemap-bench-dense")
    ap.add_argument("--spacing-6in", type=float, default=0.0)
    ap.add_argument("--spacing-16in", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "sparse.json"))
    ap.add_argument("--measured-offset", action="store_true", help="give the camera offset measured to the mm")
    ap.add_argument("--set", action="append", default=[], help="settings override section.key=value (repeatable)")
    args = ap.parse_args()

    results = [run_case(args, case, dataset(args, case)) for case in args.cases.split(",")]
    worst = max(max(r[k]["abs_error_pct"] for k in ("forward", "reverse", "total") if r[k]) for r in results)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    summary = {"benchmark": "sparse", "machine": platform.platform(), "cpus": os.cpu_count(),
               "peak_rss_mb": round(peak_mb, 1), "spacing_6in_m": args.spacing_6in,
               "spacing_16in_m": args.spacing_16in, "seed": args.seed, "measured_offset": args.measured_offset,
               "worst_abs_error_pct": round(float(np.float64(worst)), 3), "results": results}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"worst distance error {worst:.3f} %; peak RSS {peak_mb:.0f} MB; wrote {args.out}")


if __name__ == "__main__":
    main()
