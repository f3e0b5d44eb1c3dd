"""Heading errors of a mapped run along its route: where the camera's orientation drifts against the truth.

    python benchmarks/bench_heading.py RUN DATA [--tail 8] [--json-out benchmarks/results/heading.json]

RUN is a `pipemap run` result folder (trajectory.tum, run.json), DATA the simulated dataset it came from (its
ground_truth/poses.tum). The heading error of keyframe k against keyframe m is the rotation that takes the estimate's
turn from m to k onto the truth's, taken about the truth's vertical (the simulator's z axis, the normal of a level
network's plane), in millidegrees. Per straight section it prints the error of its first keyframe, of the keyframe
`--tail` before its last and of its last, each against its middle keyframe: a section whose last keyframes turn away
hands that turn to the junction solve that holds them. Per junction pass it prints the error of the turn from the
straight section before it to the one after it (its last and first keyframes): what an elbow's angle inherits.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pipemap.trajectory import read_tum


def heading_errors(run: Path, data: Path, tail: int) -> dict:
    est = read_tum(run / "trajectory.tum")
    gt = read_tum(data / "ground_truth" / "poses.tum")
    idx = np.searchsorted(gt.timestamps, est.timestamps - 1e-6)
    Re, Rg = est.rotations, gt.rotations[np.clip(idx, 0, len(gt) - 1)]

    def error(m: int, k: int) -> float:
        E = Rg[m] @ Re[m].T @ Re[k] @ Rg[k].T  # the estimate's turn m -> k against the truth's, in truth axes
        w = np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]]) / 2
        return round(float(np.degrees(np.arcsin(np.clip(w[2], -1.0, 1.0))) * 1e3), 1)

    sections = json.loads((run / "run.json").read_text())["sections"]
    straights, passes = [], []
    for i, s in enumerate(sections):
        a, b = s["first"], s["last"]
        if s["kind"] == "straight":
            m = (a + b) // 2
            straights.append({"section": s["number"], "keyframes": [a, b], "first_mdeg": error(m, a),
                              "tail_mdeg": error(m, max(m, b - tail)), "last_mdeg": error(m, b)})
        elif 0 < i < len(sections) - 1 and sections[i - 1]["kind"] == sections[i + 1]["kind"] == "straight":
            before, after = sections[i - 1]["last"], sections[i + 1]["first"]
            passes.append({"section": s["number"], "keyframes": [before, after], "turn_mdeg": error(before, after)})
    return {"run": str(run), "data": str(data), "tail": tail, "straight_sections": straights, "passes": passes}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path)
    ap.add_argument("data", type=Path)
    ap.add_argument("--tail", type=int, default=8, help="keyframes before a section's last one")
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "heading.json"))
    args = ap.parse_args()
    r = heading_errors(args.run, args.data, args.tail)
    for s in r["straight_sections"]:
        print(f"straight {s['section']} (keyframes {s['keyframes'][0]}-{s['keyframes'][1]}): heading error against "
              f"its middle: first {s['first_mdeg']:+.0f}, last-{args.tail} {s['tail_mdeg']:+.0f}, "
              f"last {s['last_mdeg']:+.0f} mdeg")
    for p in r["passes"]:
        print(f"pass {p['section']} (keyframes {p['keyframes'][0]} -> {p['keyframes'][1]}): turn error "
              f"{p['turn_mdeg']:+.0f} mdeg")
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(r, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
