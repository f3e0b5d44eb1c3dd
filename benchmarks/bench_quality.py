"""Are the self-checks' ratings right? (issue: results that say when they are wrong)

    python benchmarks/bench_quality.py [--cases DATASET[:METHOD] ...] [--out /tmp/pipemap-bench-quality]
                                       [--set section.key=value ...] [--reuse]

Runs `pipemap run` (child processes) on the benchmark scenes of the other benchmarks — the
network pipeline on the CCTV and fisheye scenes (bench_cctv.py, bench_footage.py,
bench_network.py), the straight-pipe methods on the wall-camera mounts and Table 2 scenes
(bench_mounts.py, bench_dense.py) — found in their default data folders (run those first, or
name datasets with --cases). Each rated section's path length is judged against the ground truth
(evaluation/verdicts.py) and the confusion table of error class against rating is printed:
no section more than 1 % off may be rated good, and at least 90 % of those within 0.1 % should
be. Writes benchmarks/results/quality.json.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

from pipemap.evaluation.verdicts import CLASSES, confusion, section_errors

DEFAULT_CASES = [
    "/tmp/pipemap-bench/cctv-loop-*:network",
    "/tmp/pipemap-bench/cctv-straight-*:network",
    "/tmp/pipemap-bench/paper-loop-A-640x480:network",
    "/tmp/pipemap-bench-footage/fisheye-*:network",
    "/tmp/pipemap-bench-mounts/wall-camera-*:dense-hybrid",
    "/tmp/pipemap-bench-mounts/wall-camera-*:sparse-cylinder",
    "/tmp/pipemap-bench-dense/paper-straight-*:dense-hybrid",
    "/tmp/pipemap-bench-dense/paper-straight-*:sparse-cylinder",
]


def cases(patterns: list[str]) -> list[tuple[Path, str]]:
    out = []
    for p in patterns:
        path, _, method = p.partition(":")
        for d in sorted(glob.glob(path)):
            if (Path(d) / "dataset.yaml").exists() and (Path(d) / "ground_truth").exists():
                out.append((Path(d), method or "auto"))
    return out


def run(data: Path, method: str, out: Path, overrides: list[str]) -> tuple[int, str, float]:
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "pipemap", "run", str(data), "--out", str(out), "--method", method]
    for o in overrides:
        cmd += ["--set", o]
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    text = (proc.stdout + proc.stderr).strip().splitlines()
    return proc.returncode, text[-1] if text else "", time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES)
    ap.add_argument("--out", default="/tmp/pipemap-bench-quality")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--reuse", action="store_true", help="judge result folders already in --out, run none")
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "quality.json"))
    args = ap.parse_args()
    rows, runs = [], []
    for data, method in cases(args.cases):
        out = Path(args.out) / f"{data.name}-{method}"
        if args.reuse and (out / "run.json").exists():
            rc, last, wall = 0, "(reused)", 0.0
        else:
            rc, last, wall = run(data, method, out, args.set)
        entry = {"dataset": str(data), "method": method, "exit": rc, "last_line": last, "wall_s": round(wall, 1)}
        runs.append(entry)
        if rc != 0 or not (out / "run.json").exists():
            print(f"{data.name} [{method}]: exit {rc}: {last}")
            continue
        verdict = json.loads((out / "run.json").read_text()).get("quality") or {}
        entry["verdict"] = verdict.get("line")
        for r in section_errors(out, data):
            r.update(dataset=data.name, method=method)
            rows.append(r)
            e = "-" if r["error_pct"] is None else f"{r['error_pct']:+.3f} %"
            print(f"{data.name} [{method}] section {r['section']} {r['kind']:8s} "
                  f"{(r['truth_m'] or 0):6.2f} m  error {e:>10s}  {r['rating']:7s} {'; '.join(r['reasons'])}")
        print(f"   {entry['verdict']}")
    table = confusion(rows)
    print("\nerror class      good  suspect  failed")
    for c in CLASSES:
        t = table[c]
        print(f"{c:14s} {t['good']:6d} {t['suspect']:8d} {t['failed']:7d}")
    within = table[CLASSES[0]]
    n_within = sum(within.values())
    good_share = within["good"] / n_within if n_within else None
    bad_good = table[CLASSES[2]]["good"]
    print(f"sections within 0.1 % rated good: {within['good']} of {n_within}"
          + ("" if good_share is None else f" ({100 * good_share:.0f} %, bar 90 %)"))
    print(f"sections over 1 % rated good: {bad_good} (bar 0)")
    summary = {"benchmark": "quality", "machine": platform.platform(), "cpus": os.cpu_count(), "overrides": args.set,
               "runs": runs, "sections": rows, "confusion": table,
               "within_0_1_pct_rated_good": good_share, "over_1_pct_rated_good": bad_good}
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
