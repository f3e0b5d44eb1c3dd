"""The self-checks' ratings judged against the truth: is a section rated good really right?

For every section of a result's run.json `quality` (image index ranges), the path length of its
camera centres is compared with the ground truth at the same timestamps, with no alignment. The
path is measured between poses at least `spacing_m` of true travel apart, so that the poses'
own jitter does not lengthen it; where the robot turns back within a section, each leg is judged
too and the section takes the worst (a forward leg short and a reverse leg long would cancel).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipemap.dataset import load_dataset
from pipemap.evaluation.metrics import ASSOCIATION_TOLERANCE_S, associate
from pipemap.trajectory import read_tum

SPACING_M = 0.1
MIN_LEG_M = 1.0  # legs between turn-arounds shorter than this are judged only within the section's whole path
CLASSES = ("within 0.1 %", "0.1-1 %", "over 1 %")


def _picks(travel: np.ndarray, spacing: float) -> np.ndarray:
    """Indices into a cumulative travel such that consecutive picks are at least `spacing` apart (and the last)."""
    out, last = [0], travel[0]
    for i in range(1, len(travel)):
        if travel[i] - last >= spacing:
            out.append(i)
            last = travel[i]
    if out[-1] != len(travel) - 1:
        out.append(len(travel) - 1)
    return np.array(out)


def _worst_leg(pe: np.ndarray, pg: np.ndarray) -> tuple[float, float]:
    """(true path, error %) of the section, or of its worst leg where the robot turns back (legs of at least
    MIN_LEG_M): forward short and reverse long must not cancel in the sum."""
    dg = np.diff(pg, axis=0)
    turns = np.flatnonzero(np.sum(dg[1:] * dg[:-1], axis=1) < 0) + 1  # pick where the true motion reverses
    bounds = [0, *turns.tolist(), len(pg) - 1]

    def length(p):
        return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))

    truth = length(pg)
    worst = 100.0 * (length(pe) - truth) / truth if truth > 0 else 0.0
    for a, b in zip(bounds[:-1], bounds[1:]):
        t = length(pg[a:b + 1])
        if t >= MIN_LEG_M:
            e = 100.0 * (length(pe[a:b + 1]) - t) / t
            worst = e if abs(e) > abs(worst) else worst
    return truth, worst


def section_errors(result_dir, dataset_dir, spacing_m: float = SPACING_M) -> list[dict]:
    """One row per rated section: its rating, true path length and the estimate's error in %."""
    result_dir = Path(result_dir)
    run = json.loads((result_dir / "run.json").read_text())
    quality = run.get("quality") or {}
    dataset = load_dataset(dataset_dir)
    times = dataset.times()
    est, gt = read_tum(result_dir / "trajectory.tum"), dataset.ground_truth_poses()
    ei, gi = associate(est.timestamps, gt.timestamps, ASSOCIATION_TOLERANCE_S)
    rows = []
    for s in quality.get("sections", []):
        t0, t1 = times[s["first_frame"]] - 1e-6, times[s["last_frame"]] + 1e-6
        m = (est.timestamps[ei] >= t0) & (est.timestamps[ei] <= t1)
        row = {"section": s["section"], "kind": s["kind"], "rating": s["rating"], "reasons": s["reasons"],
               "truth_m": None, "error_pct": None}
        if m.sum() >= 2:
            pe, pg = est.positions[ei[m]], gt.positions[gi[m]]
            travel = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pg, axis=0), axis=1))]
            p = _picks(travel, spacing_m)
            truth, error = _worst_leg(pe[p], pg[p])
            if truth > 0:
                row.update(truth_m=truth, error_pct=error)
        rows.append(row)
    return rows


def error_class(error_pct: float) -> str:
    e = abs(error_pct)
    return CLASSES[0] if e <= 0.1 else CLASSES[1] if e <= 1.0 else CLASSES[2]


def confusion(rows: list[dict], min_length_m: float = 0.0) -> dict:
    """{error class: {rating: count}} over the rows with a measured error and at least `min_length_m` of path."""
    table = {c: {"good": 0, "suspect": 0, "failed": 0} for c in CLASSES}
    for r in rows:
        if r["error_pct"] is None or r["truth_m"] < min_length_m:
            continue
        table[error_class(r["error_pct"])][r["rating"]] += 1
    return table


__all__ = ["CLASSES", "SPACING_M", "confusion", "error_class", "section_errors"]
