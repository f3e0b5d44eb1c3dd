"""Deformation against ground truth: a result's deformation.csv beside the dataset's
ground_truth/deformation.yaml (the simulator's oval and dented pieces).

Each slice is placed in the ground truth's frame through the rigid alignment of the keyframe positions
with the true poses, then assigned to the true piece that holds its whole band (a slice whose band crosses
a joint or an ovality taper is left out). Per source (sparse, dense):

- each oval piece: the median ovality of its slices against the true ovality (percentage points), and the
  worst slice;
- each dent: the largest inward deviation among the slices of its piece against its depth;
- the round pieces: the largest ovality any of their slices reads.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import yaml

from pipemap.errors import PipemapError
from pipemap.evaluation.align import umeyama
from pipemap.mapping.pieces import pieces_from_result
from pipemap.evaluation.metrics import associate
from pipemap.trajectory import read_tum


def read_deformation_csv(path: Path) -> list[dict]:
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as exc:
        raise PipemapError(f"cannot read: {exc}", path) from None
    return rows


def _truth_pieces(dataset_dir: Path) -> tuple[float, list[dict]]:
    path = dataset_dir / "ground_truth" / "deformation.yaml"
    if not path.exists():
        raise PipemapError("no ground-truth deformation: this dataset has no oval or dented pieces", path)
    doc = yaml.safe_load(path.read_text())
    return float(doc["radius_m"]), doc["pieces"]


def _line_pieces(dataset_dir: Path) -> list[dict]:
    """Every straight segment of network.yaml (id, start, axis, length), with its shape when it has one."""
    net = yaml.safe_load((dataset_dir / "ground_truth" / "network.yaml").read_text())
    _, shaped = _truth_pieces(dataset_dir)
    shapes = {p["id"]: p for p in shaped}
    out = []
    for s in net["segments"]:
        if s.get("kind", "line") != "line":
            continue
        a, b = np.array(s["start"], float), np.array(s["end"], float)
        out.append({"id": s["id"], "start": a, "axis": (b - a) / np.linalg.norm(b - a),
                    "length": float(np.linalg.norm(b - a)), "shape": shapes.get(s["id"])})
    return out


def deformation_errors(result_dir: str | Path, dataset_dir: str | Path, band_m: float = 0.05) -> dict:
    result_dir, dataset_dir = Path(result_dir), Path(dataset_dir)
    radius, _ = _truth_pieces(dataset_dir)
    rows = read_deformation_csv(result_dir / "deformation.csv")
    pieces = {p.name: p for p in pieces_from_result(result_dir)}
    est, gt = read_tum(result_dir / "trajectory.tum"), read_tum(dataset_dir / "ground_truth" / "poses.tum")
    ei, gi = associate(est.timestamps, gt.timestamps)
    align = umeyama(est.positions[ei], gt.positions[gi])
    lines = _line_pieces(dataset_dir)
    per: dict[tuple, list[dict]] = {}
    for row in rows:
        piece = pieces.get(row["piece"])
        if piece is None:
            continue
        h = float(row["h_m"])
        x = align.apply(piece.start + h * piece.axis)
        for line in lines:
            hl = float((x - line["start"]) @ line["axis"])
            off = np.linalg.norm(x - line["start"] - hl * line["axis"])
            shape = line["shape"]
            margin = band_m + (shape["taper_m"] if shape and shape["ovality_pct"] else 0.0)
            if off < radius and margin <= hl <= line["length"] - margin:
                per.setdefault((row["source"], line["id"]), []).append(dict(row, truth_h_m=hl))
                break
    return _figures(per, lines)


def _figures(per: dict, lines: list[dict]) -> dict:
    out: dict = {}
    by_id = {line["id"]: line for line in lines}
    for (source, pid), slices in sorted(per.items()):
        fig = out.setdefault(source, {"oval": [], "dents": [], "round": {"slices": 0, "max_ovality_pct": 0.0}})
        shape = by_id[pid]["shape"]
        ov = np.array([float(s["ovality_pct"]) for s in slices])
        if shape is None or (not shape["ovality_pct"] and not shape["dents"]):
            fig["round"]["slices"] += len(slices)
            fig["round"]["max_ovality_pct"] = max(fig["round"]["max_ovality_pct"], round(float(ov.max()), 3))
            continue
        if shape["ovality_pct"]:
            err = ov - shape["ovality_pct"]
            fig["oval"].append({"piece": pid, "true_pct": shape["ovality_pct"], "slices": len(slices),
                                "median_pct": round(float(np.median(ov)), 3),
                                "median_error_pp": round(float(np.median(ov) - shape["ovality_pct"]), 3),
                                "worst_error_pp": round(float(err[np.argmax(np.abs(err))]), 3)})
        for d in shape["dents"]:
            inward = np.array([float(s["max_inward_m"] or "nan") for s in slices])
            if not np.isfinite(inward).any():
                continue
            k = int(np.nanargmax(inward))
            fig["dents"].append({"piece": pid, "true_depth_m": d["depth_m"], "measured_m": round(float(inward[k]), 5),
                                 "error_m": round(float(inward[k] - d["depth_m"]), 5),
                                 "at_h_m": round(float(slices[k]["truth_h_m"]), 3), "true_h_m": d["h_m"]})
    return out

