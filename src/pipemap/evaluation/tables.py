"""Rich tables of an EvaluationResult, laid out like the papers' tables."""

from __future__ import annotations

import math

from rich.console import Console
from rich.table import Table

from pipemap.evaluation.evaluate import EvaluationResult
from pipemap.evaluation.metrics import DistanceRow


def _num(value: float | None, fmt: str) -> str:
    return "–" if value is None or not math.isfinite(value) else format(value, fmt)


def summary_table(result: EvaluationResult) -> Table:
    t = Table(title=f"Trajectory vs ground truth — {result.dataset}")
    t.add_column("Metric")
    t.add_column("Value", justify="right")
    t.add_row("Poses estimated / associated / ground truth",
              f"{result.estimated_poses} / {result.associated_poses} / {result.ground_truth_poses}")
    for label, a in (("rigid SE(3)", result.ate_rigid), ("Sim(3)", result.ate_sim3)):
        pct = result.ate_rmse_pct(a)
        t.add_row(f"ATE RMSE, {label} (m)", f"{_num(a.rmse, '.4f')}  ({_num(pct, '.3f')} % of path)")
        t.add_row(f"ATE max, {label} (m)", _num(a.max, ".4f"))
    t.add_row("Sim(3) scale (ground truth / estimate)", _num(result.ate_sim3.scale, ".5f"))
    t.add_row("Path length, ground truth / estimate (m)",
              f"{_num(result.gt_path_length, '.4f')} / {_num(result.est_path_length, '.4f')}")
    t.add_row("Path length error, estimate − truth",
              f"{_num(result.path_length_error, '+.4f')} m  ({_num(result.path_length_error_pct, '+.3f')} %)")
    return t


def distance_travelled_table(result: EvaluationResult) -> Table | None:
    """The 2010 report's Table 2, in millimetres; error ε = ground truth − estimate."""
    d = result.distance
    if d is None:
        return None
    t = Table(title="Distance travelled down the pipe (2010 report, Table 2)")
    t.add_column("Metric")
    t.add_column("Value", justify="right")

    def block(prefix: str, row: DistanceRow) -> None:
        t.add_row(f"{prefix}Ground Truth (mm)", _num(1000 * row.ground_truth, ".1f"))
        t.add_row(f"{prefix}Estimate (mm)", _num(1000 * row.estimate, ".1f"))
        t.add_row(f"{prefix}Error ε (mm)", _num(1000 * row.error, ".1f"))
        t.add_row(f"{prefix}Abs Error ε (%)", _num(row.abs_error_pct, ".3f"))

    if not d.forward_and_reverse:
        block("", d.forward)
    else:
        block("Forward ", d.forward)
        block("Reverse ", d.reverse)
        block("Total ", d.total)
    return t


def junction_distance_table(result: EvaluationResult) -> Table | None:
    """The fisheye paper's Table I: centre-to-centre distances; error = estimate − truth."""
    j = result.junctions
    if j is None:
        return None
    caption = f"max |error| {_num(j.max_abs_error, '.3f')} m ({_num(j.max_abs_error_pct, '.2f')} %)"
    if not j.counts_agree:
        caption += f"; {j.estimated_count} estimated vs {j.truth_count} true junctions"
    kinds = {t: tt for (t, _), (tt, _) in zip(j.matches, j.types)}
    title = ("T-intersection centre distances (fisheye paper, Table I)" if set(kinds.values()) <= {"tee"}
             else "Junction centre distances (fisheye paper, Table I; an elbow's centre is its vertex)")
    t = Table(title=title, caption=caption)
    for name in ("Distance", "Types", "Estimate ids", "Truth (m)", "Estimate (m)", "Error (m)", "Error (%)"):
        t.add_column(name, justify="left" if name in ("Distance", "Types", "Estimate ids") else "right")
    for p in j.pairs:
        t.add_row("-".join(p.truth_ids), "-".join(kinds.get(x, "?") for x in p.truth_ids), "-".join(p.estimate_ids),
                  _num(p.ground_truth, ".3f"), _num(p.estimate, ".3f"), _num(p.error, "+.3f"),
                  _num(p.error_pct, "+.2f"))
    return t


def elbow_table(result: EvaluationResult) -> Table | None:
    """Each visited elbow's angle and bend radius beside the estimate's (error = estimate - truth)."""
    j = result.junctions
    if j is None or not j.elbows:
        return None
    t = Table(title="Elbows: angle and bend radius")
    for name in ("Elbow", "Estimate id", "Angle truth (deg)", "Angle estimate (deg)", "Error (deg)",
                 "Bend radius truth (m)", "Bend radius estimate (m)", "Error (%)"):
        t.add_column(name, justify="left" if name in ("Elbow", "Estimate id") else "right")
    for e in j.elbows:
        t.add_row(e.truth_id, e.estimate_id, _num(e.truth_angle_deg, ".2f"),
                  "not estimated" if e.estimate_angle_deg is None else _num(e.estimate_angle_deg, ".2f"),
                  _num(e.angle_error_deg, "+.2f"), _num(e.truth_bend_radius_m, ".4f"),
                  "not estimated" if e.estimate_bend_radius_m is None else _num(e.estimate_bend_radius_m, ".4f"),
                  _num(e.bend_radius_error_pct, "+.2f"))
    return t


def section_table(result: EvaluationResult) -> Table | None:
    """Each straight section's length (first to last camera centre) against the truth, no alignment."""
    if not result.sections:
        return None
    worst = max(abs(s.error_pct) for s in result.sections)
    t = Table(title="Straight sections, one by one (no alignment)", caption=f"max |error| {worst:.3f} %")
    for name in ("Section", "Keyframes", "Truth (m)", "Estimate (m)", "Error (%)", "Path error (%)"):
        t.add_column(name, justify="right")
    for s in result.sections:
        t.add_row(str(s.section), f"{s.first_keyframe}-{s.last_keyframe}", _num(s.truth_m, ".3f"),
                  _num(s.estimate_m, ".3f"), _num(s.error_pct, "+.3f"), _num(s.path_error_pct, "+.3f"))
    return t


def appearance_wall_table(result: EvaluationResult) -> Table | None:
    """appearance.ply's distance to the true wall: under the ATE's alignment, and piece by piece."""
    w = result.appearance_wall
    if w is None:
        return None
    t = Table(title="Appearance map vs true wall (mm)",
              caption="global: the ATE's rigid alignment; local: each piece aligned by its own section's keyframes")
    for name in ("Alignment", "Points", "Median", "90 %", "Max", "Within 2 mm (%)"):
        t.add_column(name, justify="left" if name == "Alignment" else "right")
    for label, s in (("global", w.global_), ("local", w.local)):
        if s is not None:
            t.add_row(label, str(s.points), _num(s.median_mm, ".2f"), _num(s.p90_mm, ".2f"), _num(s.max_mm, ".2f"),
                      _num(s.within_2mm_pct, ".1f"))
    return t


def tables(result: EvaluationResult) -> list[Table]:
    """All tables that apply to this result, in reading order."""
    return [t for t in (summary_table(result), distance_travelled_table(result), junction_distance_table(result),
                        elbow_table(result), section_table(result), appearance_wall_table(result)) if t is not None]


def print_tables(result: EvaluationResult, console: Console | None = None) -> None:
    console = console or Console()
    for t in tables(result):
        console.print(t)
    for note in result.notes:
        console.print(f"[dim]note: {note}[/dim]")
