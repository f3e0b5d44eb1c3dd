"""Time per frame and peak memory of `pipemap run` as the run grows: 1,000 frames to a route as long as the fisheye
paper's dataset A (26,000 images).

    python benchmarks/bench_long_run.py [--frames 1000 5000 0] [--data /tmp/pipemap-bench]
                                        [--out /tmp/pipemap-bench/runs]

Renders the `long-loop` preset (paper-loop's 400 mm pipe and fisheye at 640x480 around a 64 m x 64 m tee loop,
route A about 25,900 frames at 1 cm) cut to each frame count (0: the whole route), cached under --data, runs
`pipemap run` on each in a child process (bench_network.run_case: wall time, CPU time, the peak resident memory of
the run and its straight-VO process together) and evaluates it. The issue's bar: time per frame flat from 1,000
to 26,000 frames and at most 1.5 GB. Prints a table and writes benchmarks/results/long_run.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_network import run_case  # noqa: E402

from pipemap.output import atomic_write_text  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def dataset(data: Path, frames: int) -> Path:
    root = data / ("long-loop-A-640x480" + (f"-{frames}" if frames else ""))
    if not (root / "dataset.yaml").exists():
        shutil.rmtree(root, ignore_errors=True)
        root.parent.mkdir(parents=True, exist_ok=True)
        # in a child process: a run started from this one would count its renderer's memory (fork) as its own
        cmd = [sys.executable, "-m", "pipemap", "simulate", "long-loop", "--out", str(root), "--width", "640",
               "--height", "480", "--route", "A", "--seed", "0", "--workers", "2"]
        subprocess.run(cmd + (["--frames", str(frames)] if frames else []), check=True, capture_output=True)
    return root


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, nargs="+", default=[1000, 5000, 0], help="frame counts (0: whole route)")
    ap.add_argument("--data", default="/tmp/pipemap-bench")
    ap.add_argument("--out", default="/tmp/pipemap-bench/runs")
    ap.add_argument("--json-out", default=str(RESULTS / "long_run.json"))
    args = ap.parse_args()
    rows = []
    for n in args.frames:
        root = dataset(Path(args.data), n)
        r = run_case(root, Path(args.out) / root.name, [])
        rows.append({k: r[k] for k in ("dataset", "frames", "keyframes", "wall_s", "cpu_s", "ms_per_frame",
                                       "frames_per_s", "peak_rss_mb", "peak_tree_rss_mb", "seconds",
                                       "path_length_error_pct", "ate_rigid_pct_of_path", "table_i_max_abs_pct",
                                       "junctions", "problems")})
        print(f"{r['frames']:6d} frames, {r['keyframes']:5d} keyframes: {r['wall_s']:8.1f} s, "
              f"{r['ms_per_frame']:6.1f} ms/frame, peak {r['peak_tree_rss_mb']:7.1f} MB "
              f"(largest process {r['peak_rss_mb']:.1f} MB), path {r['path_length_error_pct']:+.3f} %, "
              f"ATE {r['ate_rigid_pct_of_path']:.3f} % of path", flush=True)
    out = {"machine": {"cpus": __import__("os").cpu_count(), "python": platform.python_version()}, "runs": rows}
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(Path(args.json_out), json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
