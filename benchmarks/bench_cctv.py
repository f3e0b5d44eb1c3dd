"""A sewer crawler's forward-looking CCTV camera through the network pipeline: tee loop and straight pipe.

    python benchmarks/bench_cctv.py [--seeds 1 2] [--sizes 640x480 720x576] [--cases loop straight loop-B]
                                    [--effects clean cctv-h264 cctv-mjpeg] [--data /tmp/pipemap-bench]
                                    [--out /tmp/pipemap-bench/runs]

The camera: 100 deg across the image, barrel distortion, a ring of LEDs round the lens, the robot
rolling and pitching up to 1 deg (presets cctv-loop and cctv-straight; loop-B: the loop's route B, which
starts half a metre before a tee it approaches head-on, and ends past its start). `--effects`: the
footage as clean frames or through a camera-effects profile (H.264 or MJPEG with overlay, gain drift and
steps, repeated and dropped frames). For each seed, image size and effects,
renders the preset once (cached under --data), runs `pipemap run --method auto` in a child process
(its wall time and peak memory are its own; auto must choose the network pipeline) and evaluates the
result with no scale alignment: every tee-centre distance (Table I), the ATE as a share of the path
and, on the straight pipe, the distance travelled. Writes benchmarks/results/cctv.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
from pathlib import Path

from bench_network import run_case, show

from pipemap.evaluation import evaluate
from pipemap.sim.simulate import simulate

PRESETS = {"loop": ("cctv-loop", "A"), "straight": ("cctv-straight", "forward"), "loop-B": ("cctv-loop", "B")}
DEFAULT_CASES = ["loop", "straight"]


def dataset(args, case: str, size: str, seed: int, effects: str = "clean") -> Path:
    preset, route = PRESETS[case]
    width, height = (int(v) for v in size.split("x"))
    tag = "" if effects == "clean" else f"-{effects}"
    root = Path(args.data) / f"{preset}-{route}-{size}{tag}-s{seed}"
    if not (root / "dataset.yaml").exists():
        shutil.rmtree(root, ignore_errors=True)
        root.parent.mkdir(parents=True, exist_ok=True)
        simulate(preset, root, width=width, height=height, route=route, seed=seed, workers=2,
                 effects=None if effects == "clean" else effects)
    return root


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--sizes", nargs="+", default=["640x480", "720x576"])
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES, choices=list(PRESETS))
    ap.add_argument("--effects", nargs="+", default=["clean"], help="clean or a camera-effects profile")
    ap.add_argument("--data", default="/tmp/pipemap-bench")
    ap.add_argument("--out", default="/tmp/pipemap-bench/runs")
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "cctv.json"))
    args = ap.parse_args()
    results: dict = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version()}, "runs": {}}
    for case in args.cases:
        for size in args.sizes:
            for seed, effects in ((s, e) for e in args.effects for s in args.seeds):
                data = dataset(args, case, size, seed, effects)
                name = f"{case}-{size}{'' if effects == 'clean' else '-' + effects}-s{seed}"
                r = run_case(data, Path(args.out) / f"cctv-{name}", [], method="auto")
                m = evaluate(Path(args.out) / f"cctv-{name}", data)
                if m.distance is not None:
                    d = m.distance.forward
                    r["distance_error_pct"] = 100.0 * (d.estimate - d.ground_truth) / d.ground_truth
                results["runs"][name] = r
                show(name, r)
                if m.distance is not None:
                    print(f"   distance travelled {r['distance_error_pct']:+.3f} %")
    runs = results["runs"].values()
    loops = [r["table_i_max_abs_pct"] for r in runs if r.get("table_i_max_abs_pct") is not None]
    straight = [abs(r["distance_error_pct"]) for r in runs if "distance_error_pct" in r]
    results["summary"] = {
        "loop_table_i_max_abs_pct": max(loops) if loops else None,
        "loop_ate_max_pct_of_path": max((r["ate_rigid_pct_of_path"] for r in runs if r.get("table_i")), default=None),
        "straight_distance_max_abs_pct": max(straight) if straight else None,
    }
    print("\nsummary:", json.dumps(results["summary"]))
    out = Path(args.json_out)
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2, default=float) + "\n")
    print(f"written {out}")


if __name__ == "__main__":
    main()
