"""Markdown tables of a benchmark suite from the bench scripts' JSON: throughput and memory per stage,
time per frame against run length, Table I and Table 2 replicas, and the pycolmap peer.

`results` maps a result name ("network-640x480", "dense", "sparse", "peer-colmap", ...) to the JSON a
script wrote, or to `not_run(why)` when the piece did not run; every table says "not run: <why>" in
place of the rows it cannot fill, never fails on a missing piece.
"""

from __future__ import annotations

import math

GOAL_FRAMES_PER_S = 7.5  # the full fisheye pipeline at 1280x960 on 2 cores
GOAL_SIZE = "1280x960"
GOAL_PEER_SPEEDUP = 10.0
TABLE_I_PAIRS = ("T1-T2", "T2-T3", "T3-T4", "T4-T1", "T1-T3", "T2-T4")
TABLE_I_PAPER_PCT = {  # fisheye paper, Table I: signed error % of the laser distances
    "A": dict(zip(TABLE_I_PAIRS, (0.42, -0.53, -0.26, 0.63, 0.41, 0.44))),
    "B": dict(zip(TABLE_I_PAIRS, (-0.44, -0.69, -0.21, -0.07, 0.04, -0.01))),
}
NETWORK_CASES = ("A", "B", "B-no-loop-closure", "A-half")
STAGE_ORDER = ("frontend", "classification", "straight_relative", "straight_windows", "network", "loop_closure",
               "appearance", "write")


def not_run(why: str) -> dict:
    return {"not_run": why}


def why_not(entry) -> str | None:
    """The reason a result is absent, or None when it is there."""
    if entry is None:
        return "no result"
    if isinstance(entry, dict) and "not_run" in entry:
        return str(entry["not_run"])
    return None


def num(value, digits: int = 2, sign: bool = False) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:+.{digits}f}" if sign else f"{value:.{digits}f}"


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def not_run_row(width: int, label: str, why: str) -> list[str]:
    return [label, f"not run: {why}"] + [""] * (width - 2)


def network_names(results: dict) -> list[str]:
    """network-<size> results, smallest image first."""
    def pixels(name: str) -> int:
        w, _, h = name.removeprefix("network-").partition("x")
        return int(w) * int(h) if w.isdigit() and h.isdigit() else 0
    return sorted((k for k in results if k.startswith("network-")), key=pixels)


def stage_table(results: dict) -> str:
    names = network_names(results)
    stages: list[str] = []
    for name in names:
        for case in NETWORK_CASES:
            for stage in (results[name].get(case) or {}).get("seconds", {}):
                if stage not in stages and stage != "total":
                    stages.append(stage)
    stages.sort(key=lambda s: STAGE_ORDER.index(s) if s in STAGE_ORDER else len(STAGE_ORDER))
    header = ["run", "frames", "keyframes", "wall s", "frames/s"] + [f"{s} frames/s" for s in stages] + ["peak RSS MB"]
    rows = []
    for name in names or ["network"]:
        why = why_not(results.get(name))
        if why:
            rows.append(not_run_row(len(header), name, why))
            continue
        for case in NETWORK_CASES:
            r = results[name].get(case)
            if not r:
                continue
            sec = r.get("seconds", {})
            rows.append([f"{results[name].get('size', name)} {case}", r["frames"], r["keyframes"], num(r["wall_s"], 1),
                         num(r["frames_per_s"])]
                        + [num(r["frames"] / sec[s], 1) if sec.get(s) else "–" for s in stages]
                        + [num(r["peak_rss_mb"], 0)])
    return table(header, rows)


def goal_lines(results: dict) -> list[str]:
    lines = []
    r = results.get(f"network-{GOAL_SIZE}")
    why = why_not(r)
    if why:
        lines.append(f"- Goal ≥ {GOAL_FRAMES_PER_S} frames/s at {GOAL_SIZE}: not run: {why}")
    else:
        rates = {c: r[c]["frames_per_s"] for c in NETWORK_CASES if r.get(c)}
        worst = min(rates.values()) if rates else None
        met = worst is not None and worst >= GOAL_FRAMES_PER_S
        lines.append(f"- Goal ≥ {GOAL_FRAMES_PER_S} frames/s at {GOAL_SIZE}: {'met' if met else 'NOT met'} "
                     f"(slowest run {num(worst)} frames/s, wall clock of `pipemap run`)")
    peer = results.get("peer-colmap")
    why = why_not(peer) or (why_not(peer.get("pycolmap")) if peer else None) or (
        None if peer.get("ratios") else "no ratios (pipemap or pycolmap produced no trajectory)")
    if why:
        lines.append(f"- Goal ≥ {GOAL_PEER_SPEEDUP:g}× faster than pycolmap with better accuracy: not run: {why}")
    else:
        ratios = peer["ratios"]
        fast = ratios["speedup_wall"] is not None and ratios["speedup_wall"] >= GOAL_PEER_SPEEDUP
        acc = ratios.get("ate_sim3_common_peer_over_pipemap") or ratios.get("ate_sim3_peer_over_pipemap")
        better = acc is not None and acc > 1
        lines.append(f"- Goal ≥ {GOAL_PEER_SPEEDUP:g}× faster than pycolmap with better accuracy: "
                     f"{'met' if fast and better else 'NOT met'} ({num(ratios['speedup_wall'])}× faster, "
                     f"pycolmap's Sim(3) ATE {num(acc)}× pipemap's)")
    return lines


def length_table(results: dict) -> str:
    header = ["size", "frames (half)", "ms/frame (half)", "frames (full)", "ms/frame (full)", "full / half"]
    rows = []
    for name in network_names(results) or ["network"]:
        r = results.get(name)
        why = why_not(r)
        if not why and not (r.get("A") and r.get("A-half")):
            why = "needs route A and --half"
        if why:
            rows.append(not_run_row(len(header), name, why))
            continue
        half, full = r["A-half"], r["A"]
        rows.append([r.get("size", name), half["frames"], num(half["ms_per_frame"], 1), full["frames"],
                     num(full["ms_per_frame"], 1), num(full["ms_per_frame"] / half["ms_per_frame"], 3)])
    return table(header, rows)


def table_i(results: dict) -> str:
    header = ["size", "pair", "truth m", "A m", "A error %", "paper A %", "B m", "B error %", "paper B %"]
    rows = []
    for name in network_names(results) or ["network"]:
        r = results.get(name)
        why = why_not(r)
        if why:
            rows.append(not_run_row(len(header), name, why))
            continue
        by_route = {route: {p["pair"]: p for p in (r.get(route) or {}).get("table_i") or []} for route in ("A", "B")}
        pairs = [p for p in TABLE_I_PAIRS if any(p in by_route[x] for x in by_route)]
        pairs += sorted({p for x in by_route.values() for p in x} - set(pairs))
        if not pairs:
            rows.append(not_run_row(len(header), r.get("size", name), "no junction table in the results"))
            continue
        for pair in pairs:
            a, b = by_route["A"].get(pair), by_route["B"].get(pair)
            truth = (a or b)["truth_m"]
            rows.append([r.get("size", name), pair, num(truth, 3),
                         num(a and a["estimate_m"], 3), num(a and a["error_pct"], 2, True),
                         num(TABLE_I_PAPER_PCT["A"].get(pair), 2, True),
                         num(b and b["estimate_m"], 3), num(b and b["error_pct"], 2, True),
                         num(TABLE_I_PAPER_PCT["B"].get(pair), 2, True)])
        for route in ("A", "B"):
            c = r.get(route)
            if c and c.get("table_i_max_abs_pct") is not None:
                rows.append([r.get("size", name), f"max abs, route {route}", "", "", "", "", "", "",
                             f"{num(c['table_i_max_abs_pct'])} % (paper: all within 1 %)"])
    return table(header, rows)


def trajectory_table(results: dict) -> str:
    header = ["run", "path length error %", "ATE rigid mm", "ATE rigid % of path", "ATE Sim(3) % of path",
              "junctions found / true", "problems"]
    rows = []
    for name in network_names(results) or ["network"]:
        r = results.get(name)
        why = why_not(r)
        if why:
            rows.append(not_run_row(len(header), name, why))
            continue
        for case in NETWORK_CASES:
            c = r.get(case)
            if not c:
                continue
            j = c.get("junctions") or {}
            rows.append([f"{r.get('size', name)} {case}", num(c.get("path_length_error_pct"), 3, True),
                         num(1000 * c["ate_rigid_m"], 1) if c.get("ate_rigid_m") is not None else "–",
                         num(c.get("ate_rigid_pct_of_path"), 3), num(c.get("ate_sim3_pct_of_path"), 3),
                         f"{j.get('estimated', '–')} / {j.get('truth', '–')}", len(c.get("problems") or [])])
    return table(header, rows)


def _report_pct(report: dict, leg: str):
    value = report.get(leg)
    return value if not isinstance(value, (list, tuple)) else value[0]


def table_2(results: dict) -> str:
    """Distance travelled, abs error %, per case, leg and method, beside the 2010 report's figures."""
    header = ["method", "case", "frames", "leg", "truth mm", "estimate mm", "abs error %", "report %", "frames/s"]
    rows = []
    for bench, report_column in (("dense", "full search"), ("sparse", "sparse")):
        r = results.get(bench)
        why = why_not(r)
        if why:
            rows.append(not_run_row(len(header), bench, why))
            continue
        for e in r.get("results", []):
            method = e["method"] + (f"/{e['metric']}" if e.get("metric") else "")
            for leg in ("forward", "reverse", "total"):
                d = e.get(leg)
                if not d:
                    continue
                rep = (e.get("report_abs_error_pct") or {})
                ref = _report_pct(rep, leg)
                rows.append([method, e["case"], e["frames"], leg, num(d["ground_truth_mm"], 1),
                             num(d["estimate_mm"], 1), num(d["abs_error_pct"], 3),
                             f"{num(ref, 3)} ({report_column})" if ref is not None else "–",
                             num(e.get("frames_per_second"), 1)])
    return table(header, rows)


def peer_table(results: dict) -> str:
    header = ["", "frames", "wall s", "CPU s", "frames/s", "poses (registered / keyframes)", "ATE Sim(3) mm",
              "ATE Sim(3) % of path", "ATE Sim(3) mm, common frames"]
    r = results.get("peer-colmap")
    why = why_not(r)
    if why:
        return table(header, [not_run_row(len(header), "pycolmap peer", why)])
    rows = []
    common = r.get("common_frames") or {}
    for side in ("pipemap", "pycolmap"):
        e = r.get(side)
        why = why_not(e) if side in r else "not in the results"
        if why:
            rows.append(not_run_row(len(header), side, why))
            continue
        acc = e.get("accuracy") or {}
        poses = e.get("keyframes") if side == "pipemap" else e.get("registered_images")
        label = (side if side == "pipemap"
                 else f"pycolmap {r.get('pycolmap_version', '')} ({num(r.get('crop_fov_deg'), 0)}° view)")
        rows.append([label, r["frames"], num(e["wall_s"], 1), num(e.get("cpu_s"), 1),
                     num(r["frames"] / e["wall_s"], 2) if e.get("wall_s") else "–",
                     poses, num(1000 * acc["ate_sim3_m"], 2) if acc.get("ate_sim3_m") is not None else "–",
                     num(acc.get("ate_sim3_pct_of_path"), 3),
                     num(1000 * common[f"{side}_ate_sim3_m"], 2)
                     if common.get(f"{side}_ate_sim3_m") is not None else "–"])
    ratios = r.get("ratios")
    if ratios:
        rows.append(["pycolmap / pipemap", "", f"{num(ratios['speedup_wall'])}×",
                     f"{num(ratios.get('speedup_cpu'))}×", "",
                     f"{num(ratios['registered_fraction'])} registered",
                     f"{num(ratios['ate_sim3_peer_over_pipemap'])}×", "",
                     f"{num(ratios.get('ate_sim3_common_peer_over_pipemap'))}× over "
                     f"{common.get('frames', '–')} frames"])
    return table(header, rows)


def status_table(steps: list[dict]) -> str:
    rows = [[s["name"], s.get("status", "–"), num(s.get("seconds"), 1),
             f"`{s['command']}`" if s.get("command") else "–"]
            for s in steps]
    return table(["step", "status", "seconds", "command"], rows)


def markdown(suite: str, results: dict, steps: list[dict], machine: dict | None = None) -> str:
    parts = [f"# pipemap benchmark suite: {suite}", ""]
    if machine:
        parts += [", ".join(f"{k} {v}" for k, v in machine.items()), ""]
    parts += ["## Goals", "", *goal_lines(results), "",
              "## Throughput per stage and peak memory (`pipemap run`, paper-loop)", "",
              "Frames of the run per second of each stage (run.json `seconds`; `network` includes `loop_closure`); "
              "peak RSS of the `pipemap run` process.", "", stage_table(results), "",
              "## Time per frame as the run length doubles (route A: first half vs all)", "", length_table(results), "",
              "## Table I replica: T-intersection centre distances", "", table_i(results), "",
              "## Trajectory accuracy (paper-loop)", "", trajectory_table(results), "",
              "## Table 2 replica: distance travelled in a straight pipe (2010 report)", "", table_2(results), "",
              "## Peer: pycolmap incremental SfM on the same frames", "", peer_table(results), "",
              "## Steps", "", status_table(steps), ""]
    return "\n".join(parts)


def goals(results: dict) -> list[str]:
    """The goal lines without Markdown, for the suite's JSON."""
    return [line.removeprefix("- ") for line in goal_lines(results)]
