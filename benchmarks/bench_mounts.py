"""The straight-pipe methods for a wall camera at any mount: distance travelled and the estimated mount.

    python benchmarks/bench_mounts.py [--data /tmp/pipemap-bench-mounts] [--mounts 90,75,50] [--seeds 1,2]
                                      [--route forward-reverse] [--methods sparse-cylinder,dense-hybrid]
                                      [--frames N] [--set section.key=value ...]

Renders (cached under --data) the wall-camera presets: a 640x480, 70 deg camera 3 cm beside and 4 cm
below the axis of a 387.56 mm pipe, its optical axis at --mounts degrees to the pipe axis (turned
towards the direction of travel; 90, 75 and 50 are registered presets, any other angle is built the
same way here), 3.0 m forward and back at 5 mm per frame, the robot wobbling up to 1 deg and 3 mm. No
gain mask, no camera offset, no pixels-per-metre reference: every method runs with its defaults and
estimates the camera's mount itself; no scale is aligned. Each result folder is judged by
pipemap.evaluation.evaluate (distance travelled along the pipe, report eqs. 50-51), and the mount
in run.json is compared with the simulator's truth averaged over the same keyframes. Prints the
table and writes benchmarks/results/mounts.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import time
from pathlib import Path

import numpy as np

from straight_pipes import distance_rows, distance_text

from pipemap.config import load_settings
from pipemap.dataset import load_dataset
from pipemap.evaluation import evaluate
from pipemap.sim.presets import PRESETS, _wall_camera, register_preset
from pipemap.sim.simulate import simulate
from pipemap.straight import DENSE_METHODS, run_dense
from pipemap.straight.sparse.run import SPARSE_METHOD, run_sparse
from pipemap.straight.sparse.batch import mount_of

TO_PIPE = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # simulator world (x along, z up) -> (X, Y, h)


def preset(mount: float) -> str:
    name = f"wall-camera-{mount:g}"
    if name not in PRESETS:
        register_preset(name, f"wall camera at {mount:g} deg to the pipe axis", ("forward-reverse", "forward"),
                        _wall_camera(mount))
    return name


def dataset(args, mount: float, seed: int) -> Path:
    name = f"wall-camera-{mount:g}-{args.route}-s{seed}" + (f"-f{args.frames}" if args.frames else "")
    root = Path(args.data) / name
    if not (root / "dataset.yaml").exists():
        shutil.rmtree(root, ignore_errors=True)
        root.parent.mkdir(parents=True, exist_ok=True)
        simulate(preset(mount), root, seed=seed, route=args.route, frames=args.frames, workers=os.cpu_count())
    return root


def true_mount(root: Path, keyframes: list[int]) -> dict:
    """The simulator's mount averaged over the keyframes the estimate came from (the robot wobbles)."""
    gt = load_dataset(root).ground_truth_poses()
    m = np.mean([mount_of(TO_PIPE @ gt.rotations[i], gt.positions[i] @ TO_PIPE.T) for i in keyframes], axis=0)
    return {"angle_to_axis_deg": float(np.degrees(m[0])), "roll_deg": float(np.degrees(m[1])),
            "C_X_m": float(m[2]), "C_Y_m": float(m[3])}


def mount_rows(run: dict, root: Path) -> dict | None:
    est = run.get("mount")
    if not est:
        return None
    truth = true_mount(root, est["keyframes"])
    err = {"angle_deg": est["angle_to_axis_deg"] - truth["angle_to_axis_deg"],
           "roll_deg": est["roll_deg"] - truth["roll_deg"],
           "C_X_mm": 1e3 * (est["C_X_m"] - truth["C_X_m"]), "C_Y_mm": 1e3 * (est["C_Y_m"] - truth["C_Y_m"])}
    keep = ("angle_to_axis_deg", "angle_sigma_deg", "roll_deg", "roll_sigma_deg", "C_X_m", "C_X_sigma_m", "C_Y_m",
            "C_Y_sigma_m", "determined", "source", "frames_read")
    return {"estimate": {k: est[k] for k in keep}, "keyframes": len(est["keyframes"]), "truth": truth,
            "error": {k: round(v, 4) for k, v in err.items()}}


def run_case(args, mount: float, seed: int, root: Path, method: str) -> dict:
    out = Path(args.data) / "results" / f"{root.name}-{method}"
    shutil.rmtree(out, ignore_errors=True)
    settings = load_settings(None, args.set)
    t = time.perf_counter()
    if method == SPARSE_METHOD:
        res = run_sparse(root, out, settings)
        frames, extra = res.frames, {"keyframes": len(res.indices)}
    else:
        res = run_dense(root, out, settings, method)
        frames, extra = len(res.indices), {"pixels_per_metre": round(res.zeta, 3), "rectified_size": list(res.size)}
    wall = time.perf_counter() - t
    run = json.loads((out / "run.json").read_text())
    d = evaluate(out, root, write=False).distance
    m = mount_rows(run, root)
    entry = {"mount_deg": mount, "seed": seed, "dataset": root.name, "method": method, "frames": frames, **extra,
             "scale_source": run.get("scale_source"), "mount": m, "rating": run.get("quality", {}).get("rating"),
             "offset_sigma_fraction": run.get("camera_offset_m", {}).get("sigma_fraction"), "seconds": round(wall, 1),
             **distance_rows(d)}
    err = "" if m is None else (f"  mount {m['estimate']['angle_to_axis_deg']:6.2f} deg "
                                f"({m['error']['angle_deg']:+.2f}), C_X {m['error']['C_X_mm']:+.2f} mm, "
                                f"C_Y {m['error']['C_Y_mm']:+.2f} mm [{m['estimate']['source']}]")
    print(f"{mount:4g} deg s{seed} {method:16s} {distance_text(d)}{err} {entry['rating']}  {wall:5.0f} s", flush=True)
    return entry


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="/tmp/pipemap-bench-mounts")
    ap.add_argument("--mounts", default="90,75,50")
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--route", default="forward-reverse", choices=("forward-reverse", "forward"))
    ap.add_argument("--methods", default=f"{SPARSE_METHOD},dense-hybrid")
    ap.add_argument("--frames", type=int, default=None, help="only the first N frames of each route")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "mounts.json"))
    ap.add_argument("--set", action="append", default=[], help="settings override section.key=value (repeatable)")
    args = ap.parse_args()
    methods = args.methods.split(",")
    for m in methods:
        if m != SPARSE_METHOD and m not in DENSE_METHODS:
            ap.error(f"unknown method {m!r}")

    results = []
    for seed in (int(s) for s in args.seeds.split(",")):
        for mount in (float(m) for m in args.mounts.split(",")):
            root = dataset(args, mount, seed)
            results += [run_case(args, mount, seed, root, method) for method in methods]
    worst = {m: max(max(r[k]["abs_error_pct"] for k in ("forward", "reverse") if r[k]) for r in results
                    if r["method"] == m) for m in methods}
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    summary = {"benchmark": "mounts", "machine": platform.platform(), "cpus": os.cpu_count(),
               "peak_rss_mb": round(peak_mb, 1), "route": args.route, "frames": args.frames, "overrides": args.set,
               "worst_forward_or_reverse_pct": {k: round(float(v), 3) for k, v in worst.items()}, "results": results}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(summary, indent=2) + "\n")
    print("worst forward or reverse distance error: " + ", ".join(f"{k} {v:.3f} %" for k, v in worst.items())
          + f"; peak RSS {peak_mb:.0f} MB; wrote {args.out}")


if __name__ == "__main__":
    main()
