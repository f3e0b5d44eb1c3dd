"""Straight sections one by one: each section's length as the result claims it against the truth.

A result's run.json lists its straight sections (`straight_sections`: first and last keyframe
numbers, i.e. rows of trajectory.tum). For each, the distance between its first and last camera
centres and its path length are compared with the ground truth at the same timestamps, with no
alignment: this is the fisheye paper's straight-section VO judged on its own, section by section,
before anything joins the sections.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pipemap.evaluation.metrics import ASSOCIATION_TOLERANCE_S, associate, path_length, percent
from pipemap.trajectory import Trajectory

MIN_SECTION_M = 0.5  # shorter sections give percentages dominated by the end poses' noise


@dataclass(frozen=True)
class SectionError:
    section: int
    first_keyframe: int
    last_keyframe: int
    truth_m: float  # distance between the first and last camera centres
    estimate_m: float
    error_pct: float
    truth_path_m: float
    estimate_path_m: float
    path_error_pct: float

    def as_dict(self) -> dict:
        return asdict(self)


def read_sections(run_json: Path) -> list[dict]:
    if not run_json.exists():
        return []
    try:
        run = json.loads(run_json.read_text())
    except (OSError, ValueError):
        return []
    return [s for s in run.get("straight_sections") or [] if isinstance(s, dict)]


def section_errors(sections: list[dict], est: Trajectory, gt: Trajectory) -> list[SectionError]:
    """Per straight section (see the module docstring); sections shorter than MIN_SECTION_M are left out."""
    out = []
    for s in sections:
        a, b = int(s["first_keyframe"]), int(s["last_keyframe"])
        if not (0 <= a < b < len(est)):
            continue
        part = est.subset(np.arange(a, b + 1))
        ei, gi = associate(part.timestamps, gt.timestamps, ASSOCIATION_TOLERANCE_S)
        if len(ei) < 2:
            continue
        pe, pg = part.positions[ei], gt.positions[gi]
        truth, estimate = float(np.linalg.norm(pg[-1] - pg[0])), float(np.linalg.norm(pe[-1] - pe[0]))
        if truth < MIN_SECTION_M:
            continue
        tp, ep = path_length(pg), path_length(pe)
        out.append(SectionError(int(s.get("section", len(out))), a, b, truth, estimate,
                                percent(estimate - truth, truth), tp, ep, percent(ep - tp, tp)))
    return out


__all__ = ["SectionError", "read_sections", "section_errors", "MIN_SECTION_M"]
