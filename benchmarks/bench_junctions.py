"""Junctions as real networks have them (issue: tees passed straight through, stems, crosses, elbows).

    python benchmarks/bench_junctions.py [--cases tee-pass-loop:A tee-pass-loop:B elbow-cross:A ...] [--seeds 1 2]
                                         [--size 640x480] [--data /tmp/pipemap-bench-junctions] [--set k=v ...]
                                         [--specular 0]

For each preset:route and seed it renders the dataset (cached under --data), runs `pipemap run` in a child process
and judges the result against the ground truth with no scale alignment: how many junctions the map has against the
route's (found, none invented), their types, every distance between junction centres (Table I over every type,
straight-through tees and elbows included), each elbow's angle and bend radius where the map estimates them, the
ATE, and how each pass was placed (run.json junction_passes: turn of the axes, tee model, side opening) and which
passes were dropped for want of a branch or bend. Prints the table and writes benchmarks/results/junctions.json.
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

CASES = ["tee-pass-loop:A", "tee-pass-loop:B", "elbow-cross:A", "elbow-cross:B", "elbow-cross:C"]


def dataset(args, preset: str, route: str, seed: int) -> Path:
    matte = "" if args.specular is None else f"-specular{args.specular:g}"
    root = Path(args.data) / f"{preset}-{route}-{args.size}-s{seed}{matte}"
    if not (root / "dataset.yaml").exists():
        shutil.rmtree(root, ignore_errors=True)
        root.parent.mkdir(parents=True, exist_ok=True)
        width, height = (int(v) for v in args.size.split("x"))
        simulate(preset, root, width=width, height=height, route=route, seed=seed, workers=2, specular=args.specular)
    return root


def judge(out: Path, data: Path) -> dict:
    m = evaluate(out, data, write=False)
    run = json.loads((out / "run.json").read_text())
    j = m.junctions
    return {
        "types": None if j is None else [list(t) for t in j.types],
        "elbows": None if j is None else [{"id": e.truth_id, "angle_deg": e.truth_angle_deg,
                                           "estimate_angle_deg": e.estimate_angle_deg,
                                           "bend_radius_m": e.truth_bend_radius_m,
                                           "estimate_bend_radius_m": e.estimate_bend_radius_m} for e in j.elbows],
        "passes": [{k: p.get(k) for k in ("id", "type", "method", "angle_deg", "first_keyframe", "last_keyframe")}
                   for p in run.get("junction_passes", [])],
        "dropped": run.get("dropped_junction_passes", []),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=CASES, help="preset:route")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--data", default="/tmp/pipemap-bench-junctions")
    ap.add_argument("--set", action="append", default=[], help="settings override section.key=value (repeatable)")
    ap.add_argument("--specular", type=float, default=None,
                    help="render the wall with this highlight strength (0: matte; default: the preset's)")
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "junctions.json"))
    args = ap.parse_args()
    results = []
    for case in args.cases:
        preset, route = case.split(":")
        for seed in args.seeds:
            data = dataset(args, preset, route, seed)
            name = f"{preset}-{route}-s{seed}" + ("" if args.specular is None else f"-specular{args.specular:g}")
            out = Path(args.data) / "runs" / name
            r = run_case(data, out, args.set)
            r.update(case=case, seed=seed, **judge(out, data))
            show(name, r)
            found = r["junctions"] or {}
            print(f"   junctions: {found.get('estimated')} in the map, {found.get('truth')} on the route; types "
                  + ", ".join(f"{t}->{e}" for t, e in (r["types"] or [])))
            for p in r["passes"]:
                print(f"   pass {p['id']} ({p['type']}): {p['method']}, axes {p['angle_deg']} deg, "
                      f"keyframes {p['first_keyframe']}-{p['last_keyframe']}")
            for d in r["dropped"]:
                print(f"   dropped pass {d['id']} (keyframes {d['first_keyframe']}-{d['last_keyframe']}): "
                      f"{d['reason']}")
            for e in r["elbows"] or []:
                print(f"   elbow {e['id']}: angle {e['angle_deg']:.2f} deg (estimate {e['estimate_angle_deg']}), bend "
                      f"radius {e['bend_radius_m']:.3f} m (estimate {e['estimate_bend_radius_m']})")
            results.append(r)
    summary = {"benchmark": "junctions", "machine": platform.platform(), "cpus": os.cpu_count(), "size": args.size,
               "overrides": args.set, "specular": args.specular, "results": results}
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
