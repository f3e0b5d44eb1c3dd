"""How much of a run's accuracy is chance: one dataset mapped once per seed of the random choices.

    python benchmarks/bench_spread.py DATASET [--seeds 0 1 2 3] [--set section.key=value ...]
                                      [--out /tmp/pipemap-spread] [--json-out benchmarks/results/spread.json]

The front end's RANSAC draws its samples from `seed`; every seed is an equally good run. The tracks a keyframe keeps
depend on those draws, and through them the later keyframes, windows and tee solves: on paper-loop route A a
perturbation of 1e-5 px in the anchor match's start moved ATE from 5.8 to 12.0 mm and Table I from 0.04 to 0.11 %.
A figure measured on one seed is therefore one draw from a spread, and a change to the method (or its speed, which
changes its rounding) is within noise when it stays within that spread. Each seed runs `pipemap run --set seed=S`
in a child process (bench_network.run_case: wall time, CPU, peak memory) and `pipemap evaluate`; the script prints
each seed's Table I, ATE and path length and their minimum, median and maximum over the seeds.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path

import numpy as np

from bench_network import run_case

_FIGURES = ("table_i_max_abs_pct", "ate_rigid_mm", "path_length_error_pct", "wall_s", "cpu_s")


def spread(runs: list[dict]) -> dict:
    """Minimum, median and maximum over the runs of each figure that every run has."""
    out = {}
    for key in _FIGURES:
        values = [r[key] for r in runs if r.get(key) is not None]
        if len(values) == len(runs) and values:
            out[key] = {"min": float(np.min(values)), "median": float(np.median(values)), "max": float(np.max(values))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--set", action="append", default=[], help="settings override section.key=value (repeatable)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/pipemap-spread"))
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "spread.json"))
    args = ap.parse_args()
    runs = []
    for seed in args.seeds:
        r = run_case(args.dataset, args.out / f"{args.dataset.name}-seed{seed}", args.set + [f"seed={seed}"])
        r["seed"] = seed
        r["ate_rigid_mm"] = 1000 * r["ate_rigid_m"]
        runs.append(r)
        table = ", ".join(f"{p['pair']} {p['error_pct']:+.3f}" for p in r["table_i"] or [])
        print(f"seed {seed}: {r['wall_s']:.1f} s ({r['cpu_s']:.1f} CPU-s), {r['keyframes']} keyframes, "
              f"Table I max {r['table_i_max_abs_pct'] if r['table_i'] else float('nan'):.3f} % ({table}), "
              f"ATE {r['ate_rigid_mm']:.1f} mm, path {r['path_length_error_pct']:+.3f} %", flush=True)
    summary = spread(runs)
    for key, s in summary.items():
        print(f"{key:>22s}: min {s['min']:.3f}  median {s['median']:.3f}  max {s['max']:.3f}")
    result = {"benchmark": "spread", "machine": platform.platform(), "cpus": os.cpu_count(),
              "load_average": os.getloadavg(), "dataset": str(args.dataset), "overrides": args.set,
              "runs": runs, "spread": summary}
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
