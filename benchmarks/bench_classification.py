"""Straight vs T-intersection classification (fisheye paper III-B): accuracy and speed.

    python benchmarks/bench_classification.py [--quick] [--cache DIR] [--out benchmarks/results/classification.json]

Renders whole routes with pipemap.sim (small images, wide frame spacing), classifies every
frame with the default ClassificationSettings and judges against two ground truths
(pipemap.evaluation.labels.ground_truth_labels):

- `distance`: junction when the camera centre is within 2 r of a tee centroid (3D);
- `visible`: the same, but straight once the camera has passed the tee centre by more than r
  along its view (the tee is then behind the 190 degree field of view). `ceiling` is the
  accuracy a perfect image classifier could reach under the distance rule.

Per scene: accuracy before/after the temporal filter, junction clusters found vs tee visits
(one-to-one overlap with the true clusters), where the clusters start and end (signed distance
of the camera to the tee centre along its view, in pipe radii), ms per frame (in memory).
Sweeps: ratio_threshold, dark_threshold and erosion_px, one at a time around the defaults.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipemap.config import ClassificationSettings
from pipemap.dataset import load_dataset
from pipemap.evaluation.labels import ground_truth_labels
from pipemap.frontend.classification import classify_frame, junction_clusters, temporal_filter

SCENES = [  # name, preset, route, width, height, seed, spacing_m
    ("paper-A-320-s0", "paper-loop", "A", 320, 240, 0, 0.05),
    ("paper-A-320-s1", "paper-loop", "A", 320, 240, 1, 0.05),
    ("paper-A-640-s0", "paper-loop", "A", 640, 480, 0, 0.05),
    ("paper-A-1280-s0", "paper-loop", "A", 1280, 960, 0, 0.05),
    ("paper-B-320-s0", "paper-loop", "B", 320, 240, 0, 0.05),
    ("demo-A-320-s0", "demo-loop", "A", 320, 240, 0, 0.03),
    ("demo-A-320-s1", "demo-loop", "A", 320, 240, 1, 0.03),
    ("demo-A-640-s0", "demo-loop", "A", 640, 480, 0, 0.03),
    ("demo-B-320-s0", "demo-loop", "B", 320, 240, 0, 0.03),
    ("straight-320-s0", "fisheye-straight", None, 320, 240, 0, 0.05),
    ("cctv-A-640-s1", "cctv-loop", "A", 640, 480, 1, 0.03),  # forward-looking CCTV, 100 deg perspective
    ("cctv-B-640-s2", "cctv-loop", "B", 640, 480, 2, 0.03),
]
QUICK = {"paper-A-320-s0", "demo-A-320-s0", "demo-B-320-s0", "straight-320-s0"}
SWEEP_SCENES = ("paper-A-320-s0", "paper-B-320-s0", "demo-A-320-s0", "demo-B-320-s0")
RATIOS = (1.1, 1.25, 1.5, 2.0, 3.0, 5.0)
DARK = (0.08, 0.1, 0.15, 0.2, 0.25, 0.3)
EROSION = (0, 1, 2, 3)


def render(root: Path, name, preset, route, width, height, seed, spacing) -> Path:
    from pipemap.sim.simulate import simulate

    out = root / name
    if not (out / "dataset.yaml").exists():
        t = time.perf_counter()
        simulate(preset, out, width=width, height=height, seed=seed, route=route, spacing_m=spacing)
        print(f"  rendered {name} in {time.perf_counter() - t:.0f} s", flush=True)
    return out


def tee_offsets(dataset, frame_ids) -> np.ndarray:
    """Signed distance (pipe radii) of the camera to the nearest tee centre along its view: < 0 before."""
    traj, net = dataset.ground_truth_poses(), dataset.network()
    tees = np.array([j.centroid for j in net.junctions if j.type == "tee"])
    pos, fwd = traj.positions[frame_ids], traj.rotations[frame_ids][:, :, 2]
    rel = pos[:, None] - tees[None]
    k = np.linalg.norm(rel, axis=-1).argmin(axis=1)
    return np.einsum("nk,nk->n", rel[np.arange(len(k)), k], fwd) / net.radius_m


def cluster_match(found, truth) -> dict:
    def hit(a, b):
        return a[0] <= b[1] and b[0] <= a[1]

    one_to_one = len(found) == len(truth) and all(
        sum(hit(f, t) for t in truth) == 1 and sum(hit(g, f) for g in found) == 1 for f, t in zip(found, truth)
    ) and all(hit(f, t) for f, t in zip(found, truth))
    return {"found": len(found), "true": len(truth), "one_per_visit": bool(one_to_one)}


def judge(junction, raw, truth, visible) -> dict:
    return {
        "accuracy_distance_raw": float(np.mean(raw == truth)),
        "accuracy_distance": float(np.mean(junction == truth)),
        "accuracy_visible_raw": float(np.mean(raw == visible)),
        "accuracy_visible": float(np.mean(junction == visible)),
    }


def run_scene(path: Path, settings: ClassificationSettings, keep: bool) -> tuple[dict, list[np.ndarray], object]:
    """Classify every frame; the time counts classify_frame only (not PNG decoding)."""
    dataset = load_dataset(path)
    images, fcs, spent = [], [], 0.0
    for i, frame in enumerate(dataset.frames()):
        if i == 0:
            classify_frame(frame.image, dataset.camera, settings)  # geometry cache, not timed
        t = time.perf_counter()
        fcs.append(classify_frame(frame.image, dataset.camera, settings))
        spent += time.perf_counter() - t
        if keep:
            images.append(frame.image)
    ms = spent / len(fcs) * 1e3
    raw = np.array([f.is_junction for f in fcs])
    junction = temporal_filter(raw, settings.min_cluster_keyframes)
    truth, visible = ground_truth_labels(dataset, visible=False), ground_truth_labels(dataset, visible=True)
    ids = np.arange(len(fcs))
    found, true = junction_clusters(ids, junction), junction_clusters(ids, truth)
    res = {"frames": len(fcs), "size": f"{dataset.camera.width}x{dataset.camera.height}",
           "visits": list(dataset.network().visits), "ms_per_frame": ms,
           "ceiling_distance": float(1 - np.mean(truth & ~visible)),
           **judge(junction, raw, truth, visible), "clusters": cluster_match(found, true),
           "found_clusters": found, "true_clusters": true}
    if found:
        starts = tee_offsets(dataset, np.array([a for a, _ in found]))
        ends = tee_offsets(dataset, np.array([b for _, b in found]))
        res["cluster_start_r"] = [round(float(x), 2) for x in starts]
        res["cluster_end_r"] = [round(float(x), 2) for x in ends]
    return res, images, dataset


def sweep(cache: dict, base: ClassificationSettings) -> dict:
    out = {"ratio_threshold": {}, "dark_threshold": {}, "erosion_px": {}}

    def scores(settings, ratio_thresholds=(None,)):
        rows = {}
        for name, (images, dataset, truth, visible) in cache.items():
            ratios = np.array([classify_frame(im, dataset.camera, settings).ratio for im in images])
            for rt in ratio_thresholds:
                raw = ratios >= (rt or settings.ratio_threshold)
                junction = temporal_filter(raw, settings.min_cluster_keyframes)
                ids = np.arange(len(images))
                m = cluster_match(junction_clusters(ids, junction), junction_clusters(ids, truth))
                rows.setdefault(rt, {})[name] = {
                    "distance": round(float(np.mean(junction == truth)), 4),
                    "visible": round(float(np.mean(junction == visible)), 4),
                    "one_per_visit": m["one_per_visit"]}
        return rows

    for rt, row in scores(base, RATIOS).items():
        out["ratio_threshold"][str(rt)] = row
    for dt in DARK:
        out["dark_threshold"][str(dt)] = scores(base.model_copy(update={"dark_threshold": dt}))[None]
    for er in EROSION:
        out["erosion_px"][str(er)] = scores(base.model_copy(update={"erosion_px": er}))[None]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="four small scenes only")
    ap.add_argument("--scenes", nargs="+", default=None, help="only these scenes (names above)")
    ap.add_argument("--cache", type=Path, help="keep / reuse the renders in this folder")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "classification.json")
    args = ap.parse_args(argv)
    settings = ClassificationSettings()
    tmp = None
    if args.cache is None:
        tmp = tempfile.TemporaryDirectory(prefix="bench-cls-")
        root = Path(tmp.name)
    else:
        root = args.cache
        root.mkdir(parents=True, exist_ok=True)
    results, cache = {}, {}
    try:
        for name, *spec in SCENES:
            if (args.quick and name not in QUICK) or (args.scenes and name not in args.scenes):
                continue
            path = render(root, name, *spec)
            res, images, dataset = run_scene(path, settings, keep=name in SWEEP_SCENES)
            results[name] = res
            c = res["clusters"]
            print(f"{name:16s} {res['frames']:4d} frames  distance {res['accuracy_distance']:.3f} "
                  f"(raw {res['accuracy_distance_raw']:.3f}, ceiling {res['ceiling_distance']:.3f})  "
                  f"visible {res['accuracy_visible']:.3f}  clusters {c['found']}/{c['true']} "
                  f"one-per-visit {c['one_per_visit']}  {res['ms_per_frame']:.2f} ms/frame", flush=True)
            if name in SWEEP_SCENES:
                cache[name] = (images, dataset, ground_truth_labels(dataset, visible=False),
                               ground_truth_labels(dataset, visible=True))
        print("sweeping thresholds ...", flush=True)
        sweeps = sweep(cache, settings)
        for key, table in sweeps.items():
            print(f"  {key}:")
            for value, row in table.items():
                cells = "  ".join(f"{n}: {r['distance']:.3f}/{r['visible']:.3f}{'' if r['one_per_visit'] else '*'}"
                                  for n, r in row.items())
                print(f"    {value:>5s}  {cells}")
        print("  (accuracy distance/visible rule after the filter; * = not one cluster per tee visit)")
    finally:
        if tmp is not None:
            tmp.cleanup()
    doc = {"settings": settings.model_dump(mode="json"), "scenes": results, "sweeps": sweeps}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
