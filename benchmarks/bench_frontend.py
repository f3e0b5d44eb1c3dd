"""Front-end accuracy and speed against ground truth; prints and writes benchmarks/results/frontend.json.

    python benchmarks/bench_frontend.py [--sizes 640x480 1280x960] [--frames N] [--presets fisheye-straight paper-loop]

For each preset and size it renders a dataset with pipemap.sim, runs `run_tracking`, and
judges the result files (trajectory.tum, tracks.csv, frames.csv) against the ground truth:

- relative rotation / translation-direction error of consecutive keyframes;
- true correspondences: a track observation in keyframe k is ray-cast into the true pipe
  network (network.yaml: nominal cylinders) from the true pose and re-projected into keyframe
  k+1; true when within 2 px. Also the fraction consistent with the true epipolar geometry
  (spherical Sampson distance under 2 px at the image centre), which does not depend on the
  wall model (the simulator's pieces may sag away from the nominal cylinders);
- mean track length (keyframes) of tracks that stay in straight sections (camera farther than
  `junction_margin` from every junction centroid), counting tracks seen at least twice;
- keyframe gaps (largest / median spacing in images, and in true metres travelled);
- throughput (images/s of run_tracking, image decoding included) on `--threads` cores.

The judging code reads only files and ground truth; it does not import the estimators.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from pipemap.dataset import load_dataset
from pipemap.evaluation.tracking import evaluate_tracking
from pipemap.sim.simulate import wall_caster

DEFAULT_FRAMES = {"fisheye-straight": 120, "paper-loop": 260}


def in_memory_rate(dataset_path: Path, settings) -> float:
    """Images per second of the tracker alone, frames decoded beforehand."""
    from pipemap.frontend import make_tracker

    dataset = load_dataset(dataset_path)
    frames = list(dataset.frames())
    tracker = make_tracker(dataset.camera, settings.frontend, settings.seed)
    start = time.perf_counter()
    for frame in frames:
        tracker.process(frame)
    tracker.finish()
    return len(frames) / (time.perf_counter() - start)


def _simulate(preset: str, out: Path, width: int, height: int, frames: int, seed: int) -> Path:
    from pipemap.sim.simulate import simulate

    simulate(preset, out, width=width, height=height, frames=frames, seed=seed)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["fisheye-straight", "paper-loop"])
    parser.add_argument("--sizes", nargs="+", default=["640x480", "1280x960"])
    parser.add_argument("--frames", type=int, default=None,
                        help="frames per render (default: 120 of fisheye-straight, 260 of paper-loop: "
                             "through its first tee)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--tracking", choices=["flow", "descriptors"], default="flow",
                        help="frontend.tracking: Lucas-Kanade between keyframes or descriptors in every frame")
    parser.add_argument("--workdir", type=Path, default=None, help="keep rendered datasets and results here")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "frontend.json")
    args = parser.parse_args(argv)

    import cv2

    cv2.setNumThreads(args.threads)
    from pipemap.config import Settings
    from pipemap.frontend import run_tracking

    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_frontend-"))
    results = {"conditions": {"threads": args.threads, "cpu_count": os.cpu_count(), "load_average": os.getloadavg(),
                              "seed": args.seed, "tracking": args.tracking}, "runs": []}
    for preset in args.presets:
        frames = args.frames or DEFAULT_FRAMES.get(preset, 120)
        for size in args.sizes:
            w, h = (int(v) for v in size.split("x"))
            data = work / f"{preset}-{size}"
            if not (data / "dataset.yaml").exists():
                t0 = time.perf_counter()
                _simulate(preset, data, w, h, frames, args.seed)
                print(f"rendered {preset} {size} in {time.perf_counter() - t0:.1f} s", flush=True)
            out = work / f"{preset}-{size}-track"
            if out.exists():
                import shutil

                shutil.rmtree(out)
            settings = Settings(seed=args.seed)
            settings = settings.model_copy(update={"frontend": settings.frontend.model_copy(
                update={"tracking": args.tracking})})
            result = run_tracking(data, out, settings)
            figures = evaluate_tracking(out, data, wall=wall_caster(preset, w, h, frames, args.seed))
            figures.update({"preset": preset, "size": size, "frames": frames,
                            "tracking_seconds": round(result.seconds, 3),
                            "frames_per_second_in_memory": round(in_memory_rate(data, settings), 2),
                            "load_average_after": os.getloadavg()[0]})
            results["runs"].append(figures)
            print(json.dumps(figures), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
