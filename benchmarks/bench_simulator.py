"""Simulator speed and memory: frames/s of `simulate` (render + PNG writing) at 640x480.

    python benchmarks/bench_simulator.py [--frames 150] [--cores 2] [--case paper-loop:A]

Renders demo-loop (tees and straights), fisheye-straight and paper-loop at 640x480 (or the
`--case PRESET:ROUTE` given) into a temporary folder, pinned to `--cores` CPUs, with `--workers`
rendering processes. The rate counts from the first finished frame to the last (set-up --
texture baking, bearings, the exposure frame -- is reported separately); `with setup` counts the
whole run. On a shared machine wall time depends on the other work, so the CPU time (user + sys
of this process and its rendering workers, os.times) is reported too: `CPU ms/frame` over the
whole run, `setup CPU s` of this process up to the first frame, and `frames/s idle`, the rate
the CPU time allows on `--cores` cores with nothing else running (cores x frames / CPU s).
Memory: peak RSS of the process, and the RSS growth between the first and the last tenth of
the frames (must stay ~0: frames stream to disk). Prints a table and writes
benchmarks/results/simulator.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import tempfile
import time
from pathlib import Path

from pipemap.sim.simulate import simulate

CASES = [("demo-loop", "A"), ("fisheye-straight", "forward"), ("paper-loop", "A")]


def rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def cpu_s(t: os.times_result, children: bool = True) -> float:
    return t.user + t.system + (t.children_user + t.children_system if children else 0.0)


def run_case(preset: str, route: str, frames: int, width: int, height: int, workers: int | None,
             cores: int) -> dict:
    marks: list[tuple[int, float, float]] = []
    setup_cpu: list[float] = []

    def progress(i, n):
        if not setup_cpu:
            setup_cpu.append(cpu_s(os.times(), children=False) - c0)
        marks.append((i, time.perf_counter(), rss_mb()))

    with tempfile.TemporaryDirectory() as tmp:
        # workers are reaped when the run ends, so their CPU time shows in children_* by then
        t0, start = time.perf_counter(), os.times()
        c0 = cpu_s(start, children=False)
        simulate(preset, Path(tmp) / "out", width=width, height=height, frames=frames, seed=0, route=route,
                 progress=progress, workers=workers)
        total = time.perf_counter() - t0
        cpu = cpu_s(os.times()) - cpu_s(start)
    n = len(marks)
    first, last = marks[0], marks[-1]
    tenth = max(1, n // 10)
    early = max(m[2] for m in marks[:tenth])
    late = max(m[2] for m in marks[-tenth:])
    return {
        "preset": preset, "route": route, "width": width, "height": height, "frames": n, "workers": workers or "auto",
        "frames_per_s": round((n - 1) / (last[1] - first[1]), 2),
        "setup_s": round(first[1] - t0 - (last[1] - first[1]) / max(n - 1, 1), 2),
        "total_s": round(total, 2),
        "frames_per_s_with_setup": round(n / total, 2),
        "cpu_s": round(cpu, 2),
        "cpu_ms_per_frame": round(1000 * cpu / n, 1),
        "setup_cpu_s": round(setup_cpu[0], 2),
        "frames_per_s_idle": round(cores * n / cpu, 1),
        "rss_growth_mb": round(late - early, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--workers", type=int, default=None, help="rendering processes (default: one per core)")
    ap.add_argument("--case", action="append", default=None, metavar="PRESET:ROUTE",
                    help="render this preset and route instead of the default three (repeatable)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "simulator.json")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity") and args.cores:
        os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[: args.cores]))
    cases = [tuple(c.split(":", 1)) if ":" in c else (c, None) for c in args.case] if args.case else CASES
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    results = [run_case(p, r, args.frames, args.width, args.height, args.workers, cores) for p, r in cases]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    peak_worker = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"{'preset':<18}{'route':<9}{'size':<10}{'frames':>7}{'frames/s':>10}{'with setup':>11}{'setup s':>9}"
          f"{'CPU ms/frame':>13}{'setup CPU s':>12}{'frames/s idle':>14}{'RSS growth MB':>15}")
    for r in results:
        print(f"{r['preset']:<18}{str(r['route']):<9}{r['width']}x{r['height']:<6}{r['frames']:>7}"
              f"{r['frames_per_s']:>10}{r['frames_per_s_with_setup']:>11}{r['setup_s']:>9}{r['cpu_ms_per_frame']:>13}"
              f"{r['setup_cpu_s']:>12}{r['frames_per_s_idle']:>14}{r['rss_growth_mb']:>15}")
    print(f"load average at the end {os.getloadavg()[0]:.1f} (wall-time rates are shared with that load)")
    print(f"peak RSS {peak:.0f} MB (largest rendering worker {peak_worker:.0f} MB) on {cores} cores")
    doc = {"benchmark": "simulator", "cases": results, "peak_rss_mb": round(peak, 1),
           "peak_worker_rss_mb": round(peak_worker, 1),
           "load_average_1min": round(os.getloadavg()[0], 2),
           "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
           "machine": platform.machine(), "python": platform.python_version(),
           "time": time.strftime("%Y-%m-%dT%H:%M:%S")}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
