"""Dense straight-pipe VO (2010 report section 4): a replica of Table 2 on the report's pipes, rendered.

    python benchmarks/bench_dense.py [--data /tmp/pipemap-bench-dense] [--spacing-6in 0.01]
                                     [--spacing-16in 0.005] [--seed 1] [--metrics zncc,sad,ssd] [--raw]
                                     [--methods dense-full-search,dense-lk,dense-hybrid]
                                     [--cases 6in-forward,6in-forward-reverse,16in-forward-reverse]

Renders (cached under --data) paper-straight-6in forward and forward-reverse and
paper-straight-16in forward-reverse at the presets' full image sizes, with frames `--spacing-*`
apart on average (the report's runs have 1.4 mm (6 in) and 2.8 mm (16 in) between frames; fewer,
wider-spaced frames keep the render short — the per-frame shift grows, the frame count falls; a
spacing of 0 keeps the preset's own, i.e. the report's frame count).
Every dataset gets the gain mask of its camera (report section 3.2): the white-card preset of
that robot (route 6in or 16in). zeta comes from the geometry with the camera's mount offset
read from the simulator's preset (`offset_down_m`: the camera rides below the axis looking up).

Full search registers each frame against a reference frame (dense.full_search_reference_fraction)
so that its integer rounding does not accumulate at a steady speed; the report's adjacent pairs
lost about 2 % on the 16-inch run at the report's density (--spacing-16in 0).
Every method (and each --metrics metric for full search and hybrid; --raw: also without the gain
mask) runs on every case; each result folder is judged by pipemap.evaluation.evaluate
(distance travelled along the pipe, eqs. 50-51). Prints the table and writes
benchmarks/results/dense.json.
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

from straight_pipes import CASES as STRAIGHT_PIPES, dataset, distance_rows, distance_text

from pipemap.config import Settings
from pipemap.dataset import load_dataset
from pipemap.evaluation import evaluate
from pipemap.sim.presets import get_setup
from pipemap.straight import DENSE_METHODS, run_dense

CASES = {k: v for k, v in STRAIGHT_PIPES.items() if k != "16in-forward"}  # the report's dense rows
REPORT = {  # Table 2 of the 2010 report: (full search, model) abs error %
    "6in-forward": {"forward": (0.799, 0.154), "note": "dataset 1 (dataset 2: 0.890, 0.725)"},
    "6in-forward-reverse": {"forward": (0.246, 0.149), "reverse": (0.837, 0.361), "total": (0.295, 0.255)},
    "16in-forward-reverse": {"forward": (0.27, 0.84), "reverse": (3.69, 2.92), "total": (1.980, 1.879)},
}


def camera_offset(case: str, seed: int) -> float:
    """The preset's camera mount: below the axis, looking up at the wall => negative offset towards the wall."""
    preset, route = CASES[case]
    drive = get_setup(preset, route=route, seed=seed).drive
    return -float(drive.offset_down_m)


def run_case(args, case: str, root: Path, method: str, metric: str, gain_correct: bool) -> dict:
    ds = load_dataset(root)
    offset = camera_offset(case, args.seed)
    settings = Settings()
    settings.dense.metric = metric
    out = Path(args.data) / "results" / f"{root.name}-{method}-{metric}{'' if gain_correct else '-raw'}"
    shutil.rmtree(out, ignore_errors=True)
    t = time.perf_counter()
    settings = settings.model_copy(deep=True)
    settings.dense.camera_offset_m = offset
    settings.dense.gain_correct = gain_correct
    res = run_dense(root, out, settings, method)
    wall = time.perf_counter() - t
    d = evaluate(out, root).distance
    entry = {
        "case": case, "dataset": root.name, "method": method, "metric": None if method == "dense-lk" else metric,
        "frames": len(ds), "gain_corrected": ds.has_gain_mask and gain_correct, "camera_offset_m": offset,
        "pixels_per_metre": round(res.zeta, 3), "rectified_size": list(res.size),
        "frames_per_second": round(len(ds) / res.seconds["registration"], 1), "seconds": round(wall, 2),
        **distance_rows(d), "report_abs_error_pct": REPORT[case],
    }
    label = method if method == "dense-lk" else f"{method}/{metric}"
    print(f"{case:21s} {label:23s} {'gain' if entry['gain_corrected'] else 'raw ':4s} {distance_text(d)}"
          f"  {entry['frames_per_second']:5.1f} frames/s", flush=True)
    return entry


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="/tmp/pipemap-bench-dense")
    ap.add_argument("--spacing-6in", type=float, default=0.01)
    ap.add_argument("--spacing-16in", type=float, default=0.005)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--metrics", default="zncc", help="comma-separated: sad, ssd, zncc (full search and hybrid)")
    ap.add_argument("--raw", action="store_true", help="also register the frames without the gain mask (Fig. 12)")
    ap.add_argument("--methods", default=",".join(DENSE_METHODS))
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "dense.json"))
    args = ap.parse_args()

    results = []
    for case in args.cases.split(","):
        root = dataset(args, case)
        for gain in (True, False) if args.raw else (True,):
            for method in args.methods.split(","):
                metrics = ["zncc"] if method == "dense-lk" else args.metrics.split(",")
                for metric in metrics:
                    results.append(run_case(args, case, root, method, metric, gain))
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    summary = {"benchmark": "dense", "machine": platform.platform(), "cpus": os.cpu_count(),
               "peak_rss_mb": round(peak_mb, 1), "spacing_6in_m": args.spacing_6in,
               "spacing_16in_m": args.spacing_16in, "seed": args.seed, "results": results}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"peak RSS {peak_mb:.0f} MB; wrote {args.out}")


if __name__ == "__main__":
    main()
