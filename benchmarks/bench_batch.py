"""`pipemap batch` on a 2-worker local Dask cluster against the plain loop of `pipemap run`, one after another.

    python benchmarks/bench_batch.py [--runs 4] [--preset fisheye-straight] [--width 480] [--height 360]
                                     [--frames 300] [--workers 2] [--data /tmp/pipemap-bench-batch]

Renders --runs datasets of the preset (seeds 0, 1, ...; cached under --data), then, end to end as a user
would type them, each a fresh process timed by its wall clock:
  1. sequential: `pipemap run D --out seq/D` for every dataset, one after another (default threads: OpenCV's
     pool, the front end's second thread; run_pipeline holds BLAS to one thread);
  2. batch: `pipemap batch MANIFEST --out batch --workers N` (start-up of the cluster and its worker
     processes included; batch.threads_per_run = 1 holds each run's OpenCV and BLAS/OpenMP pools to one
     thread);
  3. the same batch command again (every run complete: nothing to map);
  4. the batch with a copy of the first dataset whose mask image is corrupt added to the manifest.
Compares every result folder of 2 with 1 (results.result_differences: files byte for byte, JSON as data
without its wall-time keys). Prints and writes benchmarks/results/batch.json, with the CPU seconds of 1 and
2 (the batch's worker processes included) and the load average before and after: other processes on the
machine slow both sides, and a batch of two workers takes a larger share from them than one run does.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import yaml

from pipemap.results import TIMING_KEYS, result_differences
from pipemap.sim.simulate import simulate


def datasets(args) -> list[Path]:
    roots = []
    for seed in range(args.runs):
        root = Path(args.data) / f"{args.preset}-{args.width}x{args.height}-f{args.frames}-s{seed}"
        if not (root / "dataset.yaml").exists():
            shutil.rmtree(root, ignore_errors=True)
            simulate(args.preset, root, width=args.width, height=args.height, frames=args.frames, seed=seed,
                     spacing_m=0.015 if args.preset == "fisheye-straight" else None, workers=2)
        roots.append(root.resolve())
    return roots


def corrupt_copy(root: Path) -> Path:
    bad = root.parent / "corrupt-mask"
    if not bad.exists():
        shutil.copytree(root, bad)
        doc = yaml.safe_load((bad / "dataset.yaml").read_text())
        (bad / "dataset.yaml").write_text(yaml.safe_dump(dict(doc, mask="mask.png"), sort_keys=False))
        (bad / "mask.png").write_bytes(b"\x89PNG\r\n\x1a\n not an image")
    return bad


CPU_S: dict[str, float] = {}  # CPU seconds of each kind of command and its processes (workers included)


def timed(cmd: list[str], kind: str = "") -> tuple[float, subprocess.CompletedProcess]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    CPU_S[kind] = CPU_S.get(kind, 0.0) + cpu
    return wall, done


def pipemap(*args) -> list[str]:
    return [sys.executable, "-m", "pipemap", *map(str, args)]


def summary(out: Path) -> list[dict]:
    with open(out / "batch.csv") as fh:
        return list(csv.DictReader(fh))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--preset", default="fisheye-straight")
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--height", type=int, default=360)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--data", default="/tmp/pipemap-bench-batch")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "batch.json"))
    args = ap.parse_args()
    roots = datasets(args)
    work = Path(args.data) / "results"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    manifest = work / "runs.yaml"
    manifest.write_text(yaml.safe_dump({"format": "pipemap-batch/1", "runs": [str(r) for r in roots]}))
    load_before = os.getloadavg()

    seq_runs = []
    for root in roots:
        seconds, done = timed(pipemap("run", root, "--out", work / "seq" / root.name), "sequential")
        assert done.returncode == 0, done.stderr
        seq_runs.append(round(seconds, 2))
    sequential = sum(seq_runs)
    batch_s, done = timed(pipemap("batch", manifest, "--out", work / "batch", "--workers", args.workers), "batch")
    assert done.returncode == 0, done.stdout + done.stderr
    load_after = os.getloadavg()
    rows = summary(work / "batch")
    differences = {r.name: result_differences(work / "seq" / r.name, work / "batch" / r.name) for r in roots}

    rerun_s, rerun = timed(pipemap("batch", manifest, "--out", work / "batch", "--workers", args.workers))
    rerun_rows = summary(work / "batch")
    bad = corrupt_copy(roots[0])
    manifest_bad = work / "runs-with-corrupt.yaml"
    manifest_bad.write_text(yaml.safe_dump({"runs": [str(r) for r in roots] + [str(bad)]}))
    bad_s, bad_done = timed(pipemap("batch", manifest_bad, "--out", work / "batch", "--workers", args.workers))
    bad_rows = summary(work / "batch")

    result = {
        "preset": args.preset, "size": [args.width, args.height], "frames": args.frames, "runs": args.runs,
        "workers": args.workers, "cores": os.cpu_count(), "python": platform.python_version(),
        "sequential_s": round(sequential, 2), "sequential_runs_s": seq_runs, "batch_s": round(batch_s, 2),
        "speedup": round(sequential / batch_s, 3),
        "cpu_s": {k: round(v, 1) for k, v in CPU_S.items() if k},
        "batch_rows": [{k: r[k] for k in ("run", "status", "frames", "keyframes", "junctions", "seconds")}
                       for r in rows],
        "differences_ignoring": list(TIMING_KEYS), "differences": differences,
        "rerun_s": round(rerun_s, 2), "rerun_statuses": [r["status"] for r in rerun_rows],
        "rerun_says": [line for line in rerun.stdout.splitlines() if "nothing to map" in line],
        "corrupt_s": round(bad_s, 2), "corrupt_exit": bad_done.returncode,
        "corrupt_statuses": {r["run"]: r["status"] for r in bad_rows},
        "corrupt_reason": next(r["problems"] for r in bad_rows if r["run"] == bad.name),
        "load_average_before": [round(v, 2) for v in load_before],
        "load_average_after": [round(v, 2) for v in load_after],
    }
    print(f"{args.runs} x {args.preset} {args.width}x{args.height}, {args.frames} frames:")
    print(f"  sequential pipemap run: {sequential:.1f} s ({', '.join(f'{s:.1f}' for s in seq_runs)})")
    print(f"  pipemap batch, {args.workers} workers: {batch_s:.1f} s -> {sequential / batch_s:.2f}x")
    print(f"  CPU seconds: sequential {CPU_S['sequential']:.1f}, batch {CPU_S['batch']:.1f}")
    print(f"  outputs differing from pipemap run (wall-time keys aside): "
          f"{sum(len(v) for v in differences.values())}")
    print(f"  re-run: {rerun_s:.1f} s, statuses {sorted(set(result['rerun_statuses']))}")
    print(f"  with a corrupt mask: exit {bad_done.returncode}, {result['corrupt_statuses']}; "
          f"{result['corrupt_reason']}")
    print(f"  load average before {load_before[0]:.2f}, after {load_after[0]:.2f}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
