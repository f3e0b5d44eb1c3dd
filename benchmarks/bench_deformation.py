"""Deformation every 10 cm (issue 22): ovality of a 3 % and a 6 % oval piece, a 10 mm dent, round pipe between.

    python benchmarks/bench_deformation.py [--route full|short] [--seed 0] [--size 640x480]
                                           [--data /tmp/pipemap-bench-deformation] [--set k=v ...]

Renders the deformed-pipe preset (cached under --data), runs the pipeline, and judges deformation.csv
against ground_truth/deformation.yaml per source (sparse: the points triangulated again without the
cylinder term; dense: the cylinder sweep): each oval piece's median ovality and worst slice (percentage
points), the dent's depth (the largest inward deviation of its piece's slices), the largest ovality a round
piece reads. Acceptance: ovality within 0.5 pp, dent depth within 2 mm, round under 0.5 %. Prints the
figures and writes benchmarks/results/deformation.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import time
from pathlib import Path

from pipemap.config import load_settings
from pipemap.evaluation import evaluate
from pipemap.evaluation.deformation import deformation_errors
from pipemap.pipeline import run_pipeline
from pipemap.sim.simulate import simulate


def verdict(fig: dict) -> dict:
    return {
        "ovality_within_0.5pp": all(abs(o["median_error_pp"]) <= 0.5 for o in fig["oval"]) and bool(fig["oval"]),
        "dent_within_2mm": all(abs(d["error_m"]) <= 0.002 for d in fig["dents"]) and bool(fig["dents"]),
        "round_under_0.5pct": fig["round"]["slices"] > 0 and fig["round"]["max_ovality_pct"] < 0.5,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--route", default="full", choices=["full", "short"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--data", default="/tmp/pipemap-bench-deformation")
    ap.add_argument("--set", nargs="*", default=[], help="settings overrides key=value")
    args = ap.parse_args()
    root = Path(args.data) / f"deformed-pipe-{args.route}-{args.size}-s{args.seed}"
    if not (root / "dataset.yaml").exists():
        shutil.rmtree(root, ignore_errors=True)
        root.parent.mkdir(parents=True, exist_ok=True)
        width, height = (int(v) for v in args.size.split("x"))
        simulate("deformed-pipe", root, width=width, height=height, route=args.route, seed=args.seed, workers=2)
    out = root.parent / (root.name + "-out")
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    run_pipeline(root, out, load_settings(None, args.set))
    seconds = time.perf_counter() - t0
    figures = deformation_errors(out, root)
    run = json.loads((out / "run.json").read_text())
    report = {
        "case": f"deformed-pipe:{args.route}", "seed": args.seed, "size": args.size, "settings": args.set,
        "ate_rigid_m": round(evaluate(out, root, write=False).ate_rigid.rmse, 5), "run_seconds": round(seconds, 1),
        "deformation_seconds": run["deformation"]["seconds"], "free_points": run["deformation"]["free_points"],
        "sources": {src: dict(fig, verdict=verdict(fig)) for src, fig in figures.items()},
        "machine": platform.node(),
    }
    print(json.dumps(report, indent=1))
    dest = Path(__file__).parent / "results" / "deformation.json"
    dest.parent.mkdir(exist_ok=True)
    dest.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
