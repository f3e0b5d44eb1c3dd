"""Why a straight section's last keyframes turn: the heading error along a synthetic window at its end.

    python benchmarks/bench_window_ends.py [--seeds 8] [--json-out benchmarks/results/window_ends.json]

`bench_heading.py` finds the straight VO's last ~8 keyframes of every section turned by 0.05-0.32 deg against the
section's middle. Here one synthetic straight pipe (the tests' window: 75 keyframes 2 cm apart, tracks of 3-7
keyframes, 0.3 px noise, no outliers, the first pose held and nothing else) is solved twice: as a window that
ends at keyframe 59 (the observations of keyframes 60-74 dropped) and as one that runs on to 74. Both see the same
keyframes 0-59 with the same observations; only the end differs. Each is solved with the cylinder term (tau from
the settings) and without it (tau = 0), and once more ending at 59 with the cylinder term on the points behind the
last camera only. Two remedies are measured beside them: the window ending at 59 with its axis held to the true
direction (`axis_prior`), and the window waiting 5 keyframes past 59 (`straight_vo.end_lookahead`) with the
cylinder term on the wall up to 0.05 or 0.1 m past keyframe 59 only (`end_wall_ahead_m`). Per keyframe: the RMS
over the seeds of its heading error against keyframe 30 (about the crawler's vertical, millidegrees), and of the
difference between the two windows (the end's own effect).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "backend"))
import pipe_window as scene  # the tests' synthetic window

from pipemap.backend.bundle import BundleProblem, Observations
from pipemap.config import BundleSettings
from pipemap.geometry.cylinder import fit_cylinder

FRAMES, END, MIDDLE = 75, 60, 30
SHOWN = [0, 20, 40, 45, 50, 53, 55, 57, 59]


def heading_mdeg(w: scene.PipeWindow, R: np.ndarray) -> np.ndarray:
    """(N,) heading error of each keyframe's turn from MIDDLE against the truth's, about the crawler's vertical."""
    v = -w.R[MIDDLE][:, 1]
    d = w.cylinder.direction
    v = (v - (v @ d) * d) / np.linalg.norm(v - (v @ d) * d)
    E = w.R[MIDDLE] @ R[MIDDLE].T @ R @ np.swapaxes(w.R[:len(R)], 1, 2)
    axis = np.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]], -1) / 2
    return np.degrees(np.arcsin(np.clip(axis @ v, -1.0, 1.0))) * 1e3


def solve(w: scene.PipeWindow, n: int, tau: float, behind_only: bool = False, true_axis: bool = False,
          wall_to: tuple[int, float] | None = None) -> np.ndarray:
    """Keyframe rotations (n, 3, 3) of the window of the first n keyframes. true_axis: the cylinder's axis held to
    the truth's direction; wall_to (k, m): the cylinder term on the wall up to m metres ahead of keyframe k only."""
    keep = w.obs_camera < n
    cams, pts, pix = w.obs_camera[keep], w.obs_point[keep], w.obs_pixels[keep]
    keep = np.bincount(pts, minlength=len(w.points))[pts] >= 2
    cams, pts, pix = cams[keep], pts[keep], pix[keep]
    used = np.unique(pts)
    remap = np.full(len(w.points), -1)
    remap[used] = np.arange(len(used))
    X0 = w.points0[used]
    mask = None
    axial = (w.points[used] - w.cylinder.origin) @ w.cylinder.direction
    if behind_only:
        mask = axial < (w.t[n - 1] - w.cylinder.origin) @ w.cylinder.direction
    if wall_to is not None:
        mask = axial < (w.t[wall_to[0]] - w.cylinder.origin) @ w.cylinder.direction + wall_to[1]
    on = slice(None) if wall_to is None else mask
    fit = fit_cylinder(X0[on], scene.RADIUS, reference=(w.R0[0], w.t0[0]), direction=w.t0[n - 1] - w.t0[0])
    prior = (w.cylinder.direction, np.radians(0.005)) if true_axis else None
    res = BundleProblem(w.camera, (w.R0[:n], w.t0[:n]), X0, Observations(cams, remap[pts], pix), cylinder=fit,
                        cylinder_points=mask, tau=tau, huber_px=0.5, axis_prior=prior).solve()
    return res.poses[:, :3, :3]


def rms(rows: list[np.ndarray]) -> list[float]:
    P = np.array(rows)
    return [round(float(np.sqrt(np.mean(P[:, k] ** 2))), 1) for k in SHOWN]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "window_ends.json"))
    args = ap.parse_args()
    tau = BundleSettings().tau
    runs: dict[str, list[np.ndarray]] = {k: [] for k in ("ends", "runs_on", "ends_tau0", "runs_on_tau0", "behind",
                                                         "true_axis", "waits_0.05", "waits_0.1")}
    observations = []
    for seed in range(args.seeds):
        w = scene.make_pipe_window(n_frames=FRAMES, n_points=6000, step=0.02, noise_px=0.3, outlier_frac=0.0,
                                   scale0=1.0, seed=seed)
        observations.append([int(np.sum(w.obs_camera == END - 1)), FRAMES])
        for key, n, t, behind in (("ends", END, tau, False), ("runs_on", FRAMES, tau, False),
                                  ("ends_tau0", END, 0.0, False), ("runs_on_tau0", FRAMES, 0.0, False),
                                  ("behind", END, tau, True)):
            runs[key].append(heading_mdeg(w, solve(w, n, t, behind))[:END])
        runs["true_axis"].append(heading_mdeg(w, solve(w, END, tau, true_axis=True))[:END])
        for m in (0.05, 0.1):  # straight_vo.end_lookahead = 5, end_wall_ahead_m = m
            runs[f"waits_{m}"].append(heading_mdeg(w, solve(w, END + 5, tau, wall_to=(END - 1, m)))[:END])
    table = {
        "window ends at 59, cylinder term": rms(runs["ends"]),
        "window runs on to 74, cylinder term": rms(runs["runs_on"]),
        "end effect, cylinder term": rms([a - b for a, b in zip(runs["ends"], runs["runs_on"])]),
        "window ends at 59, no cylinder term": rms(runs["ends_tau0"]),
        "end effect, no cylinder term": rms([a - b for a, b in zip(runs["ends_tau0"], runs["runs_on_tau0"])]),
        "window ends at 59, cylinder term behind the last camera only": rms(runs["behind"]),
        "window ends at 59, axis held to the true direction": rms(runs["true_axis"]),
        "runs on to 64, cylinder term on the wall to 0.05 m past 59": rms(runs["waits_0.05"]),
        "runs on to 64, cylinder term on the wall to 0.1 m past 59": rms(runs["waits_0.1"]),
    }
    print(f"RMS over {args.seeds} seeds of the heading error against keyframe {MIDDLE} (mdeg), keyframes {SHOWN}:")
    for label, row in table.items():
        print(f"  {label:>62}: {row}")
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps({"benchmark": "window_ends", "seeds": args.seeds, "keyframes": SHOWN,
                                               "tau": tau, "rms_mdeg": table}, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
