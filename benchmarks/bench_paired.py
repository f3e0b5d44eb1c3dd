"""Back-end changes measured on the same tracks: the front end once per dataset, the back end once per variant.

    python benchmarks/bench_paired.py DATASET [DATASET ...] --variant NAME[:section.key=value,...] [--variant ...]
                                      [--seed S] [--cache /tmp/pipemap-paired]

A change to the back end (windows, tee and elbow solves, pose graph) compared by two `pipemap run`s is compared
through two front ends as well: the keyframes a run keeps depend on the RANSAC draws and on rounding, and on
paper-loop route A that alone moves Table I from 0.04 to 0.2 % (bench_spread.py). Here each simulated dataset's
front end (`track_and_classify`, default settings plus --seed) runs once and is cached (pickled under --cache),
and the network back end (`map_network`, as `pipemap run` runs it) runs on it once per variant, so the differences
between variants are the back end's alone. A variant is a name and its settings overrides (`base` with none is the
default). For each dataset and variant it prints Table I's largest error (every distance between junction
centres, no scale alignment), the ATE after a Sim(3) alignment and each junction's type and angle, and writes
benchmarks/results/paired.json. The cache knows nothing of the front end's code: empty it after changing that.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
from pathlib import Path

import numpy as np
from bench_exact_observations import judged

from pipemap.config import load_settings
from pipemap.dataset import load_dataset
from pipemap.network import load_network
from pipemap.pipeline import map_network, track_and_classify
from pipemap.trajectory import read_tum


def front_end(root: Path, dataset, seed: int | None, cache: Path):
    """The dataset's tracked keyframes, from the cache when this dataset and seed have been tracked before."""
    path = cache / f"{root.resolve().as_posix().strip('/').replace('/', '_')}-seed{seed}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    front = track_and_classify(dataset, load_settings(None, [] if seed is None else [f"seed={seed}"]))
    cache.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(front))
    return front


def parse_variant(text: str) -> tuple[str, list[str]]:
    name, _, sets = text.partition(":")
    return name, [s for s in sets.split(",") if s]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("datasets", type=Path, nargs="+")
    ap.add_argument("--variant", action="append", default=[], help="NAME[:section.key=value,...] (repeatable)")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/pipemap-paired"))
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "paired.json"))
    args = ap.parse_args()
    variants = [parse_variant(v) for v in args.variant] or [("base", [])]
    extra = [] if args.seed is None else [f"seed={args.seed}"]
    runs = []
    for root in args.datasets:
        dataset = load_dataset(root)
        network = load_network(root / "ground_truth" / "network.yaml")
        front = front_end(root, dataset, args.seed, args.cache)
        truth = read_tum(root / "ground_truth" / "poses.tum")
        times = np.asarray(truth.timestamps)
        at = [int(np.argmin(np.abs(times - kf.timestamp))) for kf in front.keyframes]
        for name, sets in variants:
            net = map_network(front, dataset, load_settings(None, extra + sets))
            judged_run = judged(net, truth.positions[at], network)
            run = {"dataset": str(root), "seed": args.seed, "variant": name, "overrides": sets,
                   "table_i_max_abs_pct": judged_run.get("max_abs_pct"), "ate_mm": judged_run.get("ate_mm"),
                   "junction_distances_pct": [float(p) for p in judged_run.get("junction_distances_pct", [])],
                   "junctions": [(j.type, round(float(j.angle_deg), 3)) for j in net.tees]}
            if run["ate_mm"] is None:  # a run that turns back: forward and reverse distances
                run.update(judged_run)
                print(f"{root.name:36s} {name:12s} {judged_run}", flush=True)
            else:
                print(f"{root.name:36s} {name:12s} Table I max {run['table_i_max_abs_pct']:.3f} %, "
                      f"ATE {run['ate_mm']:.1f} mm, junctions "
                      + " ".join(f"{t}:{a:.3f}" for t, a in run["junctions"]), flush=True)
            runs.append(run)
    out = {"machine": platform.node(), "cpus": os.cpu_count(), "runs": runs}
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(out, indent=2))
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
