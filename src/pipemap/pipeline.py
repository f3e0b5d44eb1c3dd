"""`pipemap run`: the stages in order, writing the result folder of spec/formats.md.

Each frame is classified straight / junction (fisheye paper III-B) and tracked (III-A); the
keyframes stream into the straight-section VO (III-C) as they are made. T-intersections are not
modelled yet: the VO treats the run as straight sections split only where tracking is lost, and
the junction labels and clusters are recorded in frames.csv and run.json. Writes
trajectory.tum, sparse.ply, frames.csv and run.json.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from pipemap.backend.sparse_ply import write_sparse_ply
from pipemap.backend.straight import StraightResult, StraightVO
from pipemap.config import Settings
from pipemap.dataset import Dataset, load_dataset
from pipemap.frontend import FeatureTracker
from pipemap.frontend.classification import SequenceClass, SequenceClassifier
from pipemap.frontend.tracks_io import write_frames_csv
from pipemap.output import atomic_write_text, result_folder
from pipemap.trajectory import Trajectory, write_tum


@dataclass
class PipelineResult:
    out_dir: Path
    image_count: int
    keyframe_count: int
    straight: StraightResult
    seconds: dict  # per stage


def write_results(folder: Path, dataset: Dataset, image_count: int, result: StraightResult, settings: Settings,
                  seconds: dict, classes: SequenceClass | None = None) -> None:
    """trajectory.tum, sparse.ply, frames.csv and run.json into `folder`."""
    t0 = time.perf_counter()
    traj = Trajectory.from_matrices(result.indices / dataset.fps, result.poses)
    write_tum(folder / "trajectory.tum", traj,
              header="pipemap straight-section VO: keyframe T_wc in metres, world = first keyframe's camera")
    write_sparse_ply(folder / "sparse.ply", result.points)
    labels = None
    if classes is not None and len(classes.indices) == image_count:
        labels = classes.labels
    write_frames_csv(folder / "frames.csv", image_count, result.indices.tolist(), labels)
    seconds = dict(seconds)
    seconds["write"] = time.perf_counter() - t0
    from pipemap import __version__

    windows = result.windows
    run = {
        "version": __version__,
        "stage": "run",
        "input": str(dataset.root),
        "settings": settings.to_dict(),
        "pipe_radius_m": dataset.radius_m,
        "frames": image_count,
        "keyframes": len(result.indices),
        "points": len(result.points),
        "lost_keyframes": max(len(result.sections) - 1, 0),
        "sections": [s.to_dict() for s in result.sections],
        "metric_chain": ("one section: one metric chain" if len(result.sections) <= 1 else
                         "tracking was lost: each section is metric on its own (its own cylinder scale); a new "
                         "section starts at the previous keyframe's pose, the motion during the gap is not recovered"),
        "windows": [w.to_dict() for w in windows],
        "junction_clusters": None if classes is None else [list(c) for c in classes.clusters],
        "seconds": {k: round(v, 3) for k, v in seconds.items()},
    }
    atomic_write_text(folder / "run.json", json.dumps(run, indent=2) + "\n")


def run_pipeline(dataset_path, out_dir, settings: Settings | None = None,
                 progress: Callable[[int, int, int], None] | None = None) -> PipelineResult:
    """Run every stage on the dataset at `dataset_path` and write the result folder `out_dir` atomically.

    progress(done, total, keyframes) is called after every frame.
    """
    settings = settings or Settings()
    dataset = load_dataset(dataset_path)
    total = len(dataset)
    seconds = {"frontend": 0.0, "straight_relative": 0.0, "straight_windows": 0.0}
    with result_folder(Path(out_dir)) as tmp:
        tracker = FeatureTracker(dataset.camera, settings.frontend, settings.seed)
        vo = StraightVO(dataset.camera, dataset.radius_m, settings)
        start = time.perf_counter()
        done = 0
        backend = 0.0

        def feed(keyframes):
            nonlocal backend
            t = time.perf_counter()
            for kf in keyframes:
                vo.add(kf)
            backend += time.perf_counter() - t

        classifier = SequenceClassifier(dataset.camera, settings.classification)
        classify_s = 0.0
        for frame in dataset.frames():
            t = time.perf_counter()
            classifier.add(frame)
            classify_s += time.perf_counter() - t
            feed(tracker.process(frame))
            done += 1
            if progress is not None:
                progress(done, total, len(tracker.keyframes))
        feed(tracker.finish())
        t = time.perf_counter()
        result = vo.finish()
        backend += time.perf_counter() - t
        seconds["frontend"] = time.perf_counter() - start - backend - classify_s
        seconds["classification"] = classify_s
        seconds["straight_relative"] = result.seconds["relative"]
        seconds["straight_windows"] = result.seconds["windows"]
        seconds["total"] = time.perf_counter() - start
        if done == 0:
            from pipemap.errors import PipemapError

            raise PipemapError("no images could be read", dataset.root)
        write_results(tmp, dataset, done, result, settings, seconds, classifier.result())
    return PipelineResult(Path(out_dir), done, len(result.indices), result, seconds)


__all__ = ["PipelineResult", "run_pipeline", "write_results"]
