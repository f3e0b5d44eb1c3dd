"""The 2010 report's Table 2 settings, rendered once and shared by bench_dense.py and bench_sparse.py:
the straight-pipe datasets (with the robot's white-card gain mask) and the distance-travelled rows."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from pipemap.sim.simulate import simulate

CASES = {
    "6in-forward": ("paper-straight-6in", "forward"),
    "6in-forward-reverse": ("paper-straight-6in", "forward-reverse"),
    "16in-forward-reverse": ("paper-straight-16in", "forward-reverse"),
    "16in-forward": ("paper-straight-16in", "forward"),
}


def dataset(args, case: str) -> Path:
    """The case's render under args.data (args.spacing_6in / spacing_16in, 0 = the report's density;
    args.seed), with the gain mask of its robot; rendered on first use."""
    preset, route = CASES[case]
    spacing = args.spacing_6in if preset == "paper-straight-6in" else args.spacing_16in
    root = Path(args.data) / f"{preset}-{route}-{spacing}-s{args.seed}"
    if not (root / "dataset.yaml").exists():
        shutil.rmtree(root, ignore_errors=True)
        root.parent.mkdir(parents=True, exist_ok=True)
        simulate(preset, root, seed=args.seed, route=route, spacing_m=spacing if spacing > 0 else None,
                 workers=os.cpu_count())
    if not (root / "gain_mask.png").exists():
        shutil.copy(white_card(args, preset), root / "gain_mask.png")
        with open(root / "dataset.yaml", "a") as fh:
            fh.write("gain_mask: gain_mask.png\n")
    return root


def white_card(args, preset: str) -> Path:
    """The gain mask of the preset's camera (report section 3.2): the white-card preset of that robot."""
    card = Path(args.data) / f"white-{preset}-s{args.seed}"
    if (card / "gain_mask.png").exists():
        return card / "gain_mask.png"
    shutil.rmtree(card, ignore_errors=True)
    simulate("white-card", card, seed=args.seed, route="16in" if preset == "paper-straight-16in" else "6in")
    return card / "gain_mask.png"


def row(d) -> dict:
    return {"ground_truth_mm": round(d.ground_truth * 1e3, 1), "estimate_mm": round(d.estimate * 1e3, 1),
            "error_mm": round(d.error * 1e3, 1), "abs_error_pct": round(d.abs_error_pct, 3)}


def distance_rows(d) -> dict:
    """forward / reverse / total rows of a DistanceTravelled (reverse and total None for one leg)."""
    return {"forward": row(d.forward), "reverse": None if d.reverse is None else row(d.reverse),
            "total": None if d.total is None else row(d.total)}


def distance_text(d) -> str:
    """One line: ground truth, forward (and reverse, total) estimates and errors."""
    text = (f"gt {d.forward.ground_truth * 1e3:6.1f} mm  forward {d.forward.estimate * 1e3:7.1f} mm "
            f"{d.forward.abs_error_pct:6.3f} %")
    if d.reverse is not None:
        text += (f"  reverse {d.reverse.estimate * 1e3:7.1f} mm {d.reverse.abs_error_pct:6.3f} %"
                 f"  total {d.total.estimate * 1e3:6.1f} mm {d.total.abs_error_pct:6.3f} %")
    return text
