"""`pipemap demo`: simulate the demo-loop network, map it, evaluate the map and write the report and the viewer.

out_dir/dataset is the rendered dataset (with ground truth), out_dir/result the pipeline's result
folder with metrics.json, report.html and viewer.html.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from pipemap.config import Settings
from pipemap.errors import PipemapError
from pipemap.output import atomic_write_text

PRESET = "demo-loop"
SEED = 0
SPACING_M = 0.01  # metres between frames, as paper-loop: ~640 frames, about two minutes on 2 cores; at 0.02 m the
# short pieces of the demo loop kept too few keyframes and the map drifted vertically (65 % of it within 2 mm)


@dataclass
class DemoSummary:
    out_dir: Path
    dataset_dir: Path
    result_dir: Path
    report: Path
    viewer: Path  # the self-contained viewer page (pipemap report)
    frames: int  # read from the recording (repeated ones included)
    keyframes: int
    seconds: dict  # simulate, run, maps, evaluate, report, total
    path_length_error_pct: float | None = None
    ate_rmse_m: float | None = None
    tee_errors: list[dict] = field(default_factory=list)  # Table I rows: pair, truth_m, estimate_m, error_m, error_pct
    appearance_points: int | None = None
    notes: list[str] = field(default_factory=list)
    appearance_wall: dict | None = None  # metrics.json "appearance_wall": map points against the true wall


def _prepare(out_dir: Path, force: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise PipemapError("exists and is not a folder", out_dir)
    if out_dir.exists() and any(out_dir.iterdir()):
        if not force:
            raise PipemapError("already exists and is not empty; choose another --out or pass --force to replace it",
                               out_dir)
        for name in ("dataset", "result"):
            target = out_dir / name
            if target.is_dir():
                shutil.rmtree(target)
            elif target.exists():
                target.unlink()
    out_dir.mkdir(parents=True, exist_ok=True)


def run_demo(out_dir: str | Path, width: int = 640, height: int = 480,
             progress: Callable[[str, int, int], None] | None = None, *, frames: int | None = None,
             spacing_m: float = SPACING_M, force: bool = False, settings: Settings | None = None) -> DemoSummary:
    """Simulate demo-loop into out_dir/dataset, run the pipeline into out_dir/result, build the
    appearance maps if the pipeline did not, evaluate, write report.html. progress(stage, done,
    total) reports the rendering and tracking frames."""
    from pipemap.dataset import load_dataset
    from pipemap.evaluation import evaluate
    from pipemap.evaluation.report import write_report
    from pipemap.pipeline import run_pipeline
    from pipemap.sim.simulate import simulate
    from pipemap.viewer import write_viewer

    out_dir = Path(out_dir)
    _prepare(out_dir, force)
    settings = settings or Settings()
    report = progress or (lambda stage, done, total: None)
    seconds: dict[str, float] = {}
    notes: list[str] = []
    t0 = time.perf_counter()
    dataset_dir = simulate(PRESET, out_dir / "dataset", width=width, height=height, frames=frames, seed=SEED,
                           spacing_m=spacing_m, progress=lambda d, n: report("rendering", d, n))
    seconds["simulate"] = time.perf_counter() - t0
    t = time.perf_counter()
    result_dir = out_dir / "result"
    result = run_pipeline(dataset_dir, result_dir, settings, progress=lambda d, n, k=0: report("mapping", d, n))
    seconds["run"] = time.perf_counter() - t
    t = time.perf_counter()
    maps = _ensure_maps(result_dir, load_dataset(dataset_dir), settings, notes)
    seconds["maps"] = time.perf_counter() - t
    t = time.perf_counter()
    metrics = evaluate(result_dir, dataset_dir)
    seconds["evaluate"] = time.perf_counter() - t
    t = time.perf_counter()
    html = write_report(result_dir, dataset_dir)
    viewer = write_viewer(result_dir, settings=settings).path
    seconds["report"] = time.perf_counter() - t
    seconds["total"] = time.perf_counter() - t0
    tees = []
    if metrics.junctions is not None:
        tees = [{"pair": "-".join(p.truth_ids), "truth_m": p.ground_truth, "estimate_m": p.estimate,
                 "error_m": p.error, "error_pct": p.error_pct} for p in metrics.junctions.pairs]
    notes += list(metrics.notes)
    if result.quality is not None:
        notes.insert(0, f"self-checks: {result.quality.line()}")
    wall = None if metrics.appearance_wall is None else metrics.appearance_wall.as_dict()
    return DemoSummary(out_dir, Path(dataset_dir), result_dir, html, viewer, result.footage.frames,
                       result.keyframe_count,
                       seconds, _finite(metrics.path_length_error_pct), _finite(metrics.ate_rigid.rmse), tees,
                       maps, notes, wall)


def _finite(v) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


def _ensure_maps(result_dir: Path, dataset, settings: Settings, notes: list[str]) -> int | None:
    """Build appearance.ply and unrolled/ from the result's wall pieces when the pipeline has not;
    records what it did in run.json "appearance". Returns the number of appearance points."""
    from pipemap.mapping import pieces_from_result, write_maps
    from pipemap.mapping.appearance import read_appearance_ply
    from pipemap.trajectory import read_tum

    if (result_dir / "appearance.ply").exists():
        return len(read_appearance_ply(result_dir / "appearance.ply")[1])
    pieces = pieces_from_result(result_dir)
    if not pieces:
        notes.append("the result describes no wall pieces: appearance map and unrolled images skipped")
        return None
    traj = read_tum(result_dir / "trajectory.tum")
    indices = np.rint(traj.timestamps * dataset.fps).astype(int)
    info = write_maps(result_dir, dataset, indices, traj.matrices(), pieces, settings)
    run_path = result_dir / "run.json"
    run = json.loads(run_path.read_text())
    run["appearance"] = info
    stages = run.setdefault("seconds", {})
    stages.update(info["seconds"])
    if isinstance(stages.get("total"), (int, float)):
        stages["total"] = round(stages["total"] + sum(info["seconds"].values()), 3)
    atomic_write_text(run_path, json.dumps(run, indent=2) + "\n")
    return info["appearance_points"]


__all__ = ["DemoSummary", "run_demo", "PRESET", "SPACING_M"]
