"""The network pipeline on footage as inspection cameras record it (issue: image conditions).

    python benchmarks/bench_footage.py [--cases straight loop] [--effects clean cctv-h264] [--seeds 1 2]
                                       [--size 640x480] [--data /tmp/pipemap-bench-footage]

For each case, effects profile and seed it renders (cached under --data) the preset with the
simulator's camera effects (sim/effects.py; cctv-h264: H.264 at CRF 28, a burned-in distance counter
and clock, gain drifting x0.75-x1.3 with two steps, 5 % repeated and 1 % dropped frames), runs
`pipemap run` in a child process and judges the result against the ground truth of what was
written, with no scale alignment: the straight case (fisheye-straight, forward then reverse) by the
distance travelled each way, the loop case (paper-loop route A) by Table I; both by the ATE. Prints
the table and writes benchmarks/results/footage.json.
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

CASES = {"straight": ("fisheye-straight", "forward-reverse"), "loop": ("paper-loop", "A")}


def dataset(args, case: str, effects: str, seed: int) -> Path:
    preset, route = CASES[case]
    width, height = (int(v) for v in args.size.split("x"))
    root = Path(args.data) / f"{preset}-{route}-{args.size}-{effects}-s{seed}"
    if not (root / "dataset.yaml").exists():
        shutil.rmtree(root, ignore_errors=True)
        root.parent.mkdir(parents=True, exist_ok=True)
        simulate(preset, root, width=width, height=height, route=route, seed=seed, workers=2,
                 effects=None if effects == "clean" else effects)
    return root


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["straight"], choices=list(CASES))
    ap.add_argument("--effects", nargs="+", default=["clean", "cctv-h264"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--data", default="/tmp/pipemap-bench-footage")
    ap.add_argument("--set", action="append", default=[], help="settings override section.key=value (repeatable)")
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "footage.json"))
    args = ap.parse_args()
    results = []
    for case in args.cases:
        for effects in args.effects:
            for seed in args.seeds:
                data = dataset(args, case, effects, seed)
                name = f"{case}-{effects}-s{seed}"
                r = run_case(data, Path(args.data) / "runs" / name, args.set)
                d = evaluate(Path(args.data) / "runs" / name, data, write=False).distance
                def signed(row):  # estimate - truth, in % of the truth
                    return None if row is None else 100.0 * (row.estimate - row.ground_truth) / row.ground_truth
                r.update(case=case, effects=effects, seed=seed, forward_pct=signed(None if d is None else d.forward),
                         reverse_pct=signed(None if d is None else d.reverse))
                run = json.loads((Path(args.data) / "runs" / name / "run.json").read_text())
                r["footage"] = {k: run["footage"][k] for k in ("frames_read", "repeated", "dropped", "damaged")}
                r["mask"] = run["mask"]["masked_fraction"]
                show(name, r)
                if r["forward_pct"] is not None:
                    print(f"   distance forward {r['forward_pct']:+.3f} %"
                          + ("" if r["reverse_pct"] is None else f", reverse {r['reverse_pct']:+.3f} %"))
                print(f"   footage {r['footage']}, masked {r['mask']}")
                results.append(r)
    summary = {"benchmark": "footage", "machine": platform.platform(), "cpus": os.cpu_count(), "size": args.size,
               "overrides": args.set, "results": results}
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
