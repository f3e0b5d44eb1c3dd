"""report.html: a static summary of a result folder, with plots in report/ and, when metrics.json
exists, the error tables. Reads result files only (and the dataset's ground truth for the plot).

Every optional file may be missing: the report then says so instead of failing. Plain HTML,
relative links, no scripts and nothing fetched from the network.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
from pathlib import Path

import numpy as np

from pipemap.errors import PipemapError
from pipemap.output import atomic_write_bytes, atomic_write_text
from pipemap.trajectory import Trajectory, read_tum

PLOTS = "report"
THUMB_WIDTH_PX = 480
THUMB_HEIGHT_PX = 240
OPTIONAL = {
    "trajectory.tum": "keyframe trajectory",
    "junctions.yaml": "junction centres",
    "frames.csv": "per-frame labels",
    "sparse.ply": "sparse scene points",
    "appearance.ply": "dense appearance map",
    "unrolled": "unrolled wall images",
    "metrics.json": "error tables (run `pipemap evaluate RESULT DATASET` with a dataset that has ground truth)",
    "run.json": "run record (settings, timings, counts)",
}

_CSS = """body{font-family:sans-serif;margin:2em;max-width:70em;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.5em}th,td{border:1px solid #bbb;padding:0.25em 0.6em}
th{background:#eee;text-align:left}td.n{text-align:right;font-variant-numeric:tabular-nums}
.missing{color:#a40}figure{display:inline-block;margin:0 1em 1em 0}figcaption{font-size:0.9em}
img{border:1px solid #ccc}"""


def _num(value, fmt: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return format(value, fmt)


def _json(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _table(headers: list[str], rows: list[list], numeric_from: int = 1) -> str:
    out = ["<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in headers) + "</tr>"]
    for row in rows:
        cells = [f'<td{" class=n" if i >= numeric_from else ""}>{html.escape(str(v))}</td>' for i, v in enumerate(row)]
        out.append("<tr>" + "".join(cells) + "</tr>")
    return "\n".join(out) + "</table>"


def _save_figure(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# -- sections of the page ------------------------------------------------------------------------


def _summary(run: dict | None, frames_csv: Path) -> str:
    rows = []
    if run is not None:
        for key, label in (("input", "input dataset"), ("version", "pipemap version"), ("frames", "frames"),
                           ("keyframes", "keyframes"), ("points", "sparse points"),
                           ("lost_keyframes", "sections started after lost tracking"),
                           ("refused_poses", "keyframe poses refused (rotation the image motion cannot make)"),
                           ("continued_poses", "keyframe poses that continue the motion before")):
            if key in run:
                rows.append([label, run[key]])
        if isinstance(run.get("junction_passes"), list):
            passes = run["junction_passes"]
            rows.append(["tees (passes)", f"{len({j.get('id') for j in passes})} ({len(passes)})"])
        if isinstance(run.get("wall_pieces"), list):
            rows.append(["wall pieces", len(run["wall_pieces"])])
        maps = run.get("appearance")
        if isinstance(maps, dict) and "appearance_points" in maps:
            rows.append(["appearance points", maps["appearance_points"]])
    elif frames_csv.exists():
        with frames_csv.open() as fh:
            flags = [r.get("keyframe") for r in csv.DictReader(fh)]
        rows += [["frames", len(flags)],
                 ["keyframes", sum(1 for f in flags if str(f).strip() in ("1", "true", "True"))]]
    problems = run.get("problems") if run else None
    text = "<h2>Summary</h2>" + (_table(["", "value"], rows) if rows else "<p class=missing>no counts recorded</p>")
    if problems:
        text += "<p>Problems recorded by the run:</p><ul>" + "".join(
            f"<li>{html.escape(str(p))}</li>" for p in problems) + "</ul>"
    return text


def _quality(run: dict | None) -> str:
    """The self-checks: the one-line verdict and each section's rating with its reasons."""
    q = (run or {}).get("quality")
    if not q:
        return "<h2>Self-checks</h2><p class=missing>run.json has no self-checks (an older result).</p>"
    rows = [[s["section"], s["kind"], f"{s['first_frame']}-{s['last_frame']}", s["keyframes"], s["rating"],
             "; ".join(s["reasons"]) or "-"] for s in q["sections"]]
    rows += [["gap", "", f"{g['after_frame']}-{g['before_frame']}", "", "", "tracking lost: not bridged"]
             for g in q.get("gaps", [])]
    return (f"<h2>Self-checks</h2><p><b>{html.escape(q['line'])}</b></p>"
            + _table(["section", "kind", "frames", "keyframes", "rating", "why"], rows, numeric_from=6))


def _timings(run: dict | None, plots: Path) -> str:
    seconds = (run or {}).get("seconds")
    if not isinstance(seconds, dict) or not seconds:
        return "<h2>Timings</h2><p class=missing>run.json records no stage timings.</p>"
    stages = {k: float(v) for k, v in seconds.items() if isinstance(v, (int, float)) and k != "total"}
    total = seconds.get("total")
    rows = [[k, _num(v, ".2f")] for k, v in stages.items()]
    if isinstance(total, (int, float)):
        rows.append(["total", _num(float(total), ".2f")])
    text = "<h2>Timings</h2>" + _table(["stage", "seconds"], rows)
    if stages:
        plt = _pyplot()
        fig, ax = plt.subplots(figsize=(6, 0.35 * len(stages) + 1))
        names = list(stages)[::-1]
        ax.barh(names, [stages[n] for n in names], color="#4a7")
        ax.set_xlabel("seconds")
        ax.set_title("wall time per stage" + (f" (total {total:.1f} s)" if isinstance(total, (int, float)) else ""))
        _save_figure(fig, plots / "timings.png")
        text += f'<p><img src="{PLOTS}/timings.png" alt="time per stage"></p>'
    return text


def _junction_centres(path: Path) -> np.ndarray:
    from pipemap.evaluation.evaluate import read_junctions

    try:
        return read_junctions(path)[1]
    except PipemapError:
        return np.zeros((0, 3))


def _trajectory(result_dir: Path, dataset_dir: Path | None, plots: Path) -> str:
    path = result_dir / "trajectory.tum"
    if not path.exists():
        return "<h2>Trajectory</h2><p class=missing>no trajectory.tum: nothing to plot.</p>"
    try:
        est = read_tum(path)
    except PipemapError as exc:
        return f"<h2>Trajectory</h2><p class=missing>{html.escape(exc.line())}</p>"
    junctions = _junction_centres(result_dir / "junctions.yaml") if (result_dir / "junctions.yaml").exists() \
        else np.zeros((0, 3))
    gt, truth_junctions, note = _ground_truth(dataset_dir)
    est_xyz, caption = est.positions, "estimate in its own frame, plane of most motion"
    if gt is not None:
        from pipemap.evaluation.metrics import ASSOCIATION_TOLERANCE_S, associate, ate

        ei, gi = associate(est.timestamps, gt.timestamps, ASSOCIATION_TOLERANCE_S)
        if len(ei) >= 2:
            align = ate(est.positions[ei], gt.positions[gi], with_scale=False).alignment
            est_xyz = align.apply(est.positions)
            junctions = align.apply(junctions) if len(junctions) else junctions
            caption = "estimate rigidly aligned to ground truth (as pipemap evaluate does), seen from above (x-y)"
        else:
            gt, note = None, "the trajectory shares no timestamps with the ground truth"
    if gt is not None:
        basis = np.eye(3)[:, :2]
    else:
        centred = est_xyz - est_xyz.mean(axis=0)
        basis = np.linalg.svd(centred, full_matrices=False)[2][:2].T if len(est_xyz) > 2 else np.eye(3)[:, :2]
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 6))
    if gt is not None:
        g = gt.positions @ basis
        ax.plot(g[:, 0], g[:, 1], color="0.6", lw=2.5, label="ground truth")
        if len(truth_junctions):
            tj = truth_junctions @ basis
            ax.scatter(tj[:, 0], tj[:, 1], marker="s", s=70, facecolors="none", edgecolors="0.3",
                       label="true junctions")
    p = est_xyz @ basis
    ax.plot(p[:, 0], p[:, 1], color="#c30", lw=1.2, label="estimate (keyframes)")
    ax.plot(p[:1, 0], p[:1, 1], "o", color="#c30")
    if len(junctions):
        j = junctions @ basis
        ax.scatter(j[:, 0], j[:, 1], marker="x", s=70, color="#04a", label="estimated junctions")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)" if gt is not None else "first principal direction (m)")
    ax.set_ylabel("y (m)" if gt is not None else "second principal direction (m)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    _save_figure(fig, plots / "trajectory.png")
    text = f'<h2>Trajectory</h2><figure><img src="{PLOTS}/trajectory.png" alt="trajectory from above">' \
           f"<figcaption>{html.escape(caption)}; o marks the start</figcaption></figure>"
    if note:
        text += f"<p class=missing>{html.escape(note)}</p>"
    return text


def _ground_truth(dataset_dir: Path | None) -> tuple[Trajectory | None, np.ndarray, str | None]:
    if dataset_dir is None:
        return None, np.zeros((0, 3)), "no dataset given: the plot shows no ground truth"
    gt_path = dataset_dir / "ground_truth" / "poses.tum"
    if not gt_path.exists():
        return None, np.zeros((0, 3)), f"the dataset has no ground truth ({gt_path} is missing)"
    try:
        gt = read_tum(gt_path)
    except PipemapError as exc:
        return None, np.zeros((0, 3)), exc.line()
    centres = np.zeros((0, 3))
    net_path = dataset_dir / "ground_truth" / "network.yaml"
    if net_path.exists():
        from pipemap.network import load_network

        try:
            centres = np.array([j.centroid for j in load_network(net_path).junctions]).reshape(-1, 3)
        except PipemapError:
            pass
    return gt, centres, None


def _errors(metrics: dict | None) -> str:
    if metrics is None:
        return ("<h2>Errors against ground truth</h2><p class=missing>no metrics.json: run "
                "<code>pipemap evaluate RESULT DATASET</code> with a dataset that has ground truth to add the "
                "error tables.</p>")
    text = [f"<h2>Errors against ground truth</h2><p>dataset {html.escape(str(metrics.get('dataset', '?')))}</p>"]
    rows = []
    poses = metrics.get("poses") or {}
    rows.append(["poses estimated / associated / ground truth",
                 f"{poses.get('estimated', '–')} / {poses.get('associated', '–')} / {poses.get('ground_truth', '–')}"])
    for key, label in (("rigid", "rigid SE(3)"), ("sim3", "Sim(3)")):
        a = (metrics.get("ate") or {}).get(key) or {}
        rows.append([f"ATE RMSE, {label}",
                     f"{_num(a.get('rmse_m'), '.4f')} m ({_num(a.get('rmse_pct_of_path'), '.3f')} % of path)"])
        rows.append([f"ATE max, {label}", f"{_num(a.get('max_m'), '.4f')} m"])
    pl = metrics.get("path_length") or {}
    rows.append(["path length, truth / estimate",
                 f"{_num(pl.get('ground_truth_m'), '.4f')} / {_num(pl.get('estimate_m'), '.4f')} m"])
    rows.append(["path length error", f"{_num(pl.get('error_m'), '+.4f')} m ({_num(pl.get('error_pct'), '+.3f')} %)"])
    text.append("<h3>Trajectory</h3>" + _table(["metric", "value"], rows))
    j = metrics.get("junctions")
    if j:
        pairs = [["-".join(p.get("truth_ids", [])), "-".join(p.get("estimate_ids", [])),
                  _num(p.get("ground_truth_m"), ".3f"), _num(p.get("estimate_m"), ".3f"),
                  _num(p.get("error_m"), "+.3f"), _num(p.get("error_pct"), "+.2f")] for p in j.get("pairs", [])]
        text.append("<h3>T-intersection centre distances (fisheye paper, Table I)</h3>" + _table(
            ["distance", "estimate ids", "truth (m)", "estimate (m)", "error (m)", "error (%)"], pairs, 2))
        text.append(f"<p>max |error| {_num(j.get('max_abs_error_m'), '.3f')} m "
                    f"({_num(j.get('max_abs_error_pct'), '.2f')} %); {j.get('estimated_count', '?')} estimated, "
                    f"{j.get('ground_truth_count', '?')} true junctions</p>")
        elbows = j.get("elbows") or []
        if elbows:
            def est(block: dict, fmt: str) -> str:
                return _num(block.get("estimate"), fmt) if block.get("estimated") else "not estimated"

            rows = [[e["truth_id"], e["estimate_id"], _num(e["angle_deg"]["ground_truth"], ".2f"),
                     est(e["angle_deg"], ".2f"), _num(e["angle_deg"].get("error"), "+.2f"),
                     _num(e["bend_radius_m"]["ground_truth"], ".4f"), est(e["bend_radius_m"], ".4f"),
                     _num(e["bend_radius_m"].get("error_pct"), "+.2f")] for e in elbows]
            text.append("<h3>Elbows: angle and bend radius</h3>" + _table(
                ["elbow", "estimate id", "angle truth (deg)", "angle estimate (deg)", "error (deg)",
                 "bend radius truth (m)", "bend radius estimate (m)", "error (%)"], rows, 2))
    d = metrics.get("distance_travelled")
    if d:
        blocks = [(k, d[k]) for k in ("forward", "reverse", "total") if isinstance(d.get(k), dict)]
        rows = [[k, _num(1000 * b["ground_truth_m"], ".1f"), _num(1000 * b["estimate_m"], ".1f"),
                 _num(1000 * b["error_m"], "+.1f"), _num(b.get("abs_error_pct"), ".3f")] for k, b in blocks
                if None not in (b.get("ground_truth_m"), b.get("estimate_m"), b.get("error_m"))]
        text.append("<h3>Distance travelled down the pipe (2010 report, Table 2)</h3>" + _table(
            ["", "ground truth (mm)", "estimate (mm)", "error (mm)", "abs error (%)"], rows))
    sections = metrics.get("sections") or []
    if sections:
        rows = [[s.get("section"), f"{s.get('first_keyframe')}-{s.get('last_keyframe')}", _num(s.get("truth_m"), ".3f"),
                 _num(s.get("estimate_m"), ".3f"), _num(s.get("error_pct"), "+.3f")] for s in sections]
        text.append("<h3>Straight sections, one by one</h3>" + _table(
            ["section", "keyframes", "truth (m)", "estimate (m)", "error (%)"], rows, 2))
    wall = metrics.get("appearance_wall")
    if wall:
        rows = [[label, s.get("points"), _num(s.get("median_mm"), ".2f"), _num(s.get("p90_mm"), ".2f"),
                 _num(s.get("max_mm"), ".2f"), _num(s.get("within_2mm_pct"), ".1f")]
                for label, s in (("global", wall.get("global")), ("local", wall.get("local"))) if isinstance(s, dict)]
        text.append("<h3>Appearance map vs true wall</h3>" + _table(
            ["alignment", "points", "median (mm)", "90 % (mm)", "max (mm)", "within 2 mm (%)"], rows) +
            "<p>global: the ATE's rigid alignment; local: each wall piece aligned by its own straight section's "
            "keyframes (positions and orientations)</p>")
    notes = metrics.get("notes") or []
    if notes:
        text.append("<ul>" + "".join(f"<li>{html.escape(str(n))}</li>" for n in notes) + "</ul>")
    return "\n".join(text)


def _maps(result_dir: Path, plots: Path) -> str:
    import cv2

    text = ["<h2>Wall maps</h2>"]
    ply = result_dir / "appearance.ply"
    if ply.exists():
        text.append(f'<p><a href="appearance.ply">appearance.ply</a>: {_ply_vertices(ply)} points '
                    f"({ply.stat().st_size / 1e6:.1f} MB), grey level per wall point</p>")
    else:
        text.append("<p class=missing>no appearance.ply: the dense appearance map was not built.</p>")
    pngs = sorted((result_dir / "unrolled").glob("*.png")) if (result_dir / "unrolled").is_dir() else []
    if not pngs:
        text.append("<p class=missing>no unrolled/ images.</p>")
        return "\n".join(text)
    for png in pngs:
        img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        if img is None:
            text.append(f"<p class=missing>cannot read {html.escape(png.name)}</p>")
            continue
        meta = _json(png.with_suffix(".json")) or {}
        scale = min(1.0, THUMB_WIDTH_PX / img.shape[1], THUMB_HEIGHT_PX / img.shape[0])
        thumb = cv2.resize(img, (max(1, round(img.shape[1] * scale)), max(1, round(img.shape[0] * scale))),
                           interpolation=cv2.INTER_AREA)
        ok, data = cv2.imencode(".png", thumb)
        name = f"thumb-{png.stem}.png"
        if ok:
            atomic_write_bytes(plots / name, data.tobytes())
        px = meta.get("metres_per_pixel_along") or meta.get("metres_per_pixel")
        length = (img.shape[1] - 1) * px if isinstance(px, (int, float)) else None
        caption = f"{png.stem}: {_num(length, '.2f')} m along, {_num(px and 1000 * px, '.1f')} mm per pixel"
        text.append(f'<figure><a href="unrolled/{html.escape(png.name)}"><img src="{PLOTS}/{name}" '
                    f'alt="unrolled wall {html.escape(png.stem)}"></a><figcaption>{html.escape(caption)}'
                    f"</figcaption></figure>")
    text.append("<p>Columns run along the pipe, rows around it (see each image's JSON); black is wall no keyframe "
                "saw.</p>")
    return "\n".join(text)


def _ply_vertices(path: Path) -> str:
    try:
        with path.open("rb") as fh:
            for _ in range(30):
                line = fh.readline().decode("ascii", "replace").strip()
                if line.startswith("element vertex"):
                    return line.split()[-1]
                if line == "end_header":
                    break
    except OSError:
        pass
    return "?"


def write_report(result_dir: str | Path, dataset_dir: str | Path | None = None) -> Path:
    """Write result_dir/report.html and its plots in result_dir/report/; returns the HTML path.
    dataset_dir: the dataset (for ground truth in the plot); by default run.json's input, if it exists."""
    result_dir = Path(result_dir)
    if not result_dir.is_dir():
        raise PipemapError("result folder not found" if not result_dir.exists() else "not a folder", result_dir)
    run = _json(result_dir / "run.json")
    if dataset_dir is None and run and isinstance(run.get("input"), str) and Path(run["input"]).is_dir():
        dataset_dir = Path(run["input"])
    dataset_dir = Path(dataset_dir) if dataset_dir is not None else None
    plots = result_dir / PLOTS
    plots.mkdir(exist_ok=True)
    missing = [f"<li><code>{html.escape(name)}</code>: {html.escape(what)}</li>" for name, what in OPTIONAL.items()
               if not (result_dir / name).exists()
               or (name == "unrolled" and not any((result_dir / name).glob("*.png")))]
    title = f"pipemap report: {result_dir.resolve().name}"
    parts = [f"<!DOCTYPE html><html><head><meta charset=utf-8><title>{html.escape(title)}</title>"
             f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>",
             _summary(run, result_dir / "frames.csv"),
             _quality(run),
             _trajectory(result_dir, dataset_dir, plots),
             _errors(_json(result_dir / "metrics.json")),
             _maps(result_dir, plots),
             _timings(run, plots)]
    if missing:
        parts.append("<h2>Missing from this result</h2><ul class=missing>" + "".join(missing) + "</ul>")
    parts.append("</body></html>\n")
    out = result_dir / "report.html"
    atomic_write_text(out, "\n".join(parts))
    return out


__all__ = ["write_report"]
