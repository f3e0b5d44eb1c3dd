"""The whole fisheye pipeline on the paper's tee loop: Table I replica, ATE, wall time and peak memory.

    python benchmarks/bench_network.py [--width 640 --height 480] [--routes A B] [--half]
                                       [--data /tmp/pipemap-bench] [--out /tmp/pipemap-bench/runs]

For each route of `paper-loop` (A: one lap, no revisit, so no loop closure; B: revisits the side
T1-T4, so loop closure applies), renders the dataset once (cached under --data), runs `pipemap run`
in a child process (so its wall time and peak resident memory, its straight-VO process included, are its own)
and `pipemap evaluate`,
and reports every pairwise tee-centre distance against the truth (the fisheye paper's Table I), the
straight sections one by one, the path-length error and the ATE without scale alignment. Route B
also runs with loop closure off, to show what it adds. --half repeats route A on its first half of
frames, to show that time per frame stays flat as the run grows. Writes
benchmarks/results/network-<width>x<height>.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tree_memory import TreeMemory

from pipemap.evaluation import evaluate


def dataset(args, route: str, frames: int | None = None) -> Path:
    name = f"paper-loop-{route}-{args.width}x{args.height}" + (f"-{frames}" if frames else "")
    root = Path(args.data) / name
    if not (root / "dataset.yaml").exists():
        shutil.rmtree(root, ignore_errors=True)
        root.parent.mkdir(parents=True, exist_ok=True)
        # in a child process: a run started from this one would count its renderer's memory (fork) as its own
        cmd = [sys.executable, "-m", "pipemap", "simulate", "paper-loop", "--out", str(root),
               "--width", str(args.width), "--height", str(args.height), "--route", route, "--seed", str(args.seed),
               "--workers", "2"]
        subprocess.run(cmd + (["--frames", str(frames)] if frames else []), check=True, capture_output=True)
    return root


def run_case(data: Path, out: Path, overrides: list[str], method: str | None = None) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "pipemap", "run", str(data), "--out", str(out)]
    if method is not None:
        cmd += ["--method", method]
    for o in overrides:
        cmd += ["--set", o]
    t = time.perf_counter()
    with tempfile.TemporaryFile("w+") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, text=True)
        memory = TreeMemory(proc.pid)
        # wait4 gives this child's own resource use (RUSAGE_CHILDREN would be the largest child so far).
        _, status, usage = os.wait4(proc.pid, 0)
        tree_peak = memory.stop()
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t
        log.seek(0)
        output = log.read().strip()
    if proc.returncode != 0:
        raise SystemExit(f"pipemap run failed on {data}: {output.splitlines()[-1] if output else proc.returncode}")
    m = evaluate(out, data)
    run = json.loads((out / "run.json").read_text())
    j = m.junctions
    return {
        "dataset": str(data),
        "overrides": overrides,
        "frames": run["frames"],
        "keyframes": run["keyframes"],
        "wall_s": round(wall, 2),
        "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
        "peak_rss_mb": round(usage.ru_maxrss / 1024, 1),  # Linux: KiB; its largest process
        # the run and its straight-VO process together, sampled; never below the largest one's high-water mark,
        # which the kernel keeps exactly (a sample can miss a short peak)
        "peak_tree_rss_mb": round(max(tree_peak, usage.ru_maxrss / 1024), 1),
        "ms_per_frame": round(1000 * wall / run["frames"], 2),
        "frames_per_s": round(run["frames"] / wall, 2),
        "seconds": run["seconds"],
        "path_length_error_pct": m.path_length_error_pct,
        "ate_rigid_m": m.ate_rigid.rmse,
        "ate_rigid_pct_of_path": m.ate_rmse_pct(m.ate_rigid),
        "ate_sim3_pct_of_path": m.ate_rmse_pct(m.ate_sim3),
        "table_i": None if j is None else [
            {"pair": "-".join(p.truth_ids), "truth_m": p.ground_truth, "estimate_m": p.estimate,
             "error_m": p.error, "error_pct": p.error_pct} for p in j.pairs],
        "table_i_max_abs_pct": None if j is None else j.max_abs_error_pct,
        "junctions": None if j is None else {"estimated": j.estimated_count, "truth": j.truth_count},
        "sections": [s.as_dict() for s in m.sections],
        "problems": run.get("problems", []),
        "method": output.splitlines()[0] if output.startswith("method:") else None,
        "loop_closure": run.get("loop_closure"),
    }


def show(name: str, r: dict) -> None:
    print(f"\n== {name}: {r['frames']} frames, {r['keyframes']} keyframes, {r['wall_s']} s "
          f"({r['frames_per_s']} frames/s, {r['ms_per_frame']} ms/frame), peak {r['peak_tree_rss_mb']} MB "
          f"(largest process {r['peak_rss_mb']} MB)")
    print(f"   path length {r['path_length_error_pct']:+.3f} %, ATE rigid {1000 * r['ate_rigid_m']:.1f} mm "
          f"({r['ate_rigid_pct_of_path']:.3f} % of path), Sim(3) {r['ate_sim3_pct_of_path']:.3f} %")
    if r["table_i"]:
        print("   Table I: " + ", ".join(f"{p['pair']} {p['error_pct']:+.3f} %" for p in r["table_i"])
              + f"  (max |error| {r['table_i_max_abs_pct']:.3f} %)")
    if r["sections"]:
        print("   sections: " + ", ".join(f"{s['section']}: {s['error_pct']:+.3f} %" for s in r["sections"]))
    if r.get("junctions"):
        print(f"   junctions: {r['junctions']['estimated']} found, {r['junctions']['truth']} true")
    for p in r["problems"]:
        print(f"   problem: {p}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--routes", nargs="+", default=["A", "B"])
    ap.add_argument("--half", action="store_true", help="also route A on its first half of frames")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data", default="/tmp/pipemap-bench")
    ap.add_argument("--out", default="/tmp/pipemap-bench/runs")
    ap.add_argument("--set", action="append", default=[], help="settings override section.key=value (repeatable)")
    ap.add_argument("--json-out", default=None,
                    help="where to write the JSON (default benchmarks/results/network-WxH.json)")
    args = ap.parse_args()
    size = f"{args.width}x{args.height}"
    results: dict = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version()}, "size": size}
    for route in args.routes:
        data = dataset(args, route)
        cases = {f"{route}": list(args.set)}
        if route == "B":
            cases[f"{route}-no-loop-closure"] = [*args.set, "loop_closure.enabled=false"]
        for name, overrides in cases.items():
            r = run_case(data, Path(args.out) / f"{name}-{size}", overrides)
            results[name] = r
            show(name, r)
    if args.half and "A" in results:
        frames = results["A"]["frames"] // 2
        r = run_case(dataset(args, "A", frames), Path(args.out) / f"A-half-{size}", list(args.set))
        results["A-half"] = r
        show("A, first half", r)
        print(f"\n   time per frame: full {results['A']['ms_per_frame']} ms, half {r['ms_per_frame']} ms")
    out = Path(args.json_out) if args.json_out else Path(__file__).parent / "results" / f"network-{size}.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2, default=float) + "\n")
    print(f"\nwritten {out}")


if __name__ == "__main__":
    main()
