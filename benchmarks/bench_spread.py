"""How much of a run's accuracy is chance: one dataset mapped once per seed of the random choices.

    python benchmarks/bench_spread.py DATASET [--seeds 0 1 2 3] [--set section.key=value ...]
                                      [--out /tmp/pipemap-spread] [--json-out benchmarks/results/spread.json]
                                      [--baseline SPREAD.json ...] [--reuse SPREAD.json ...]

The front end's RANSAC draws its samples from `seed`; every seed is an equally good run. The tracks a keyframe keeps
depend on those draws, and through them the later keyframes, windows and tee solves: on paper-loop route A a
perturbation of 1e-5 px in the anchor match's start moved ATE from 5.8 to 12.0 mm and Table I from 0.04 to 0.11 %.
A figure measured on one seed is therefore one draw from a spread, and a change to the method (or its speed, which
changes its rounding) is within noise when it stays within that spread. Each seed runs `pipemap run --set seed=S`
in a child process (bench_network.run_case: wall time, CPU, peak memory) and `pipemap evaluate`; the script prints
each seed's Table I, ATE and path length and their minimum, median, maximum, mean and standard deviation over the
seeds, and each Table I pair's signed mean and standard deviation.

Four seeds are few: on route A seeds 0-3 gave Table I within 0.040-0.081 % and seeds 4-7 of the same code 0.126-0.230 %.
--baseline takes the JSON of earlier runs of this script (their runs pooled, e.g. the same code on other seeds) and
compares each figure and each pair's signed error with them: the difference of the means, its standard error and
Welch's t-test (scipy), so that "unchanged within noise" is a p-value rather than a look at two small spreads.
--reuse takes the runs from such files instead of running (the DATASET argument then only names them).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path

import numpy as np
from scipy import stats

from bench_network import run_case

_FIGURES = ("table_i_max_abs_pct", "ate_rigid_mm", "path_length_error_pct", "wall_s", "cpu_s")


def _summary(values: list[float]) -> dict:
    v = np.asarray(values, float)
    return {"min": float(np.min(v)), "median": float(np.median(v)), "max": float(np.max(v)), "mean": float(np.mean(v)),
            "sd": float(np.std(v, ddof=1)) if len(v) > 1 else float("nan")}


def figures(runs: list[dict]) -> dict[str, list[float]]:
    """{figure: its value in every run} for each figure every run has, and "pair T1-T2" ... for each Table I pair's
    signed error (%) where every run has that pair."""
    out = {}
    for key in _FIGURES:
        values = [r[key] for r in runs if r.get(key) is not None]
        if len(values) == len(runs) and values:
            out[key] = values
    pairs: dict[str, list[float]] = {}
    for r in runs:
        for p in r.get("table_i") or []:
            pairs.setdefault(p["pair"], []).append(p["error_pct"])
    out.update({f"pair {name}": v for name, v in pairs.items() if len(v) == len(runs)})
    return out


def spread(runs: list[dict]) -> dict:
    """Minimum, median, maximum, mean and standard deviation over the runs of each figure every run has (and of
    each Table I pair's signed error)."""
    return {key: _summary(values) for key, values in figures(runs).items()}


def compare(runs: list[dict], baseline: list[dict]) -> dict:
    """Each figure both sets of runs have: the difference of the means (runs - baseline), its standard error and
    Welch's two-sided p-value (NaN with fewer than two runs on a side)."""
    now, before = figures(runs), figures(baseline)
    out = {}
    for key in now.keys() & before.keys():
        a, b = np.asarray(now[key], float), np.asarray(before[key], float)
        if min(len(a), len(b)) < 2:
            se = p = float("nan")
        else:
            va, vb = np.var(a, ddof=1) / len(a), np.var(b, ddof=1) / len(b)
            se = float(np.sqrt(va + vb))
            if se > 1e-12:  # Welch's t with its Satterthwaite degrees of freedom (scipy's ttest_ind, equal_var=False)
                dof = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
                p = float(2 * stats.t.sf(abs(a.mean() - b.mean()) / se, dof))
            else:  # every run the same on both sides
                p = float(abs(a.mean() - b.mean()) <= 1e-12)
        out[key] = {"difference": float(a.mean() - b.mean()), "se": se, "p": p, "runs": len(a),
                    "baseline_runs": len(b)}
    return dict(sorted(out.items()))


def print_run(r: dict) -> None:
    table = ", ".join(f"{p['pair']} {p['error_pct']:+.3f}" for p in r["table_i"] or [])
    print(f"seed {r['seed']}: {r['wall_s']:.1f} s ({r['cpu_s']:.1f} CPU-s), {r['keyframes']} keyframes, "
          f"Table I max {r['table_i_max_abs_pct'] if r['table_i'] else float('nan'):.3f} % ({table}), "
          f"ATE {r['ate_rigid_mm']:.1f} mm, path {r['path_length_error_pct']:+.3f} %", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--set", action="append", default=[], help="settings override section.key=value (repeatable)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/pipemap-spread"))
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "spread.json"))
    ap.add_argument("--baseline", type=Path, nargs="+", default=[],
                    help="spread JSON files of earlier runs (pooled) to compare with")
    ap.add_argument("--reuse", type=Path, nargs="+", default=[], help="spread JSON files whose runs to take (pooled) "
                    "instead of running")
    args = ap.parse_args()
    baseline = [r for path in args.baseline for r in json.loads(path.read_text())["runs"]]
    runs = [r for path in args.reuse for r in json.loads(path.read_text())["runs"]]
    for seed in [] if args.reuse else args.seeds:
        r = run_case(args.dataset, args.out / f"{args.dataset.name}-seed{seed}", args.set + [f"seed={seed}"])
        r["seed"] = seed
        r["ate_rigid_mm"] = 1000 * r["ate_rigid_m"]
        runs.append(r)
        print_run(r)
    if args.reuse:
        for r in runs:
            print_run(r)
    summary = spread(runs)
    for key, s in summary.items():
        print(f"{key:>22s}: min {s['min']:.3f}  median {s['median']:.3f}  max {s['max']:.3f}  "
              f"mean {s['mean']:.3f}  sd {s['sd']:.3f}")
    result = {"benchmark": "spread", "machine": platform.platform(), "cpus": os.cpu_count(),
              "load_average": os.getloadavg(), "dataset": str(args.dataset), "overrides": args.set,
              "runs": runs, "spread": summary}
    if baseline:
        result["baseline"] = [str(p) for p in args.baseline]
        result["against_baseline"] = compare(runs, baseline)
        print(f"against the baseline ({len(baseline)} runs): difference of the means +- its standard error, Welch p")
        for key, c in result["against_baseline"].items():
            print(f"{key:>22s}: {c['difference']:+.3f} +- {c['se']:.3f}  p {c['p']:.3f}")
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
