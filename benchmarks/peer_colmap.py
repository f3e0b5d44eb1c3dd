"""A peer on the same frames: pycolmap incremental SfM against `pipemap run`, wall time, registered
images and ATE after Sim(3) alignment, and pipemap's ratios to it.

    python benchmarks/peer_colmap.py --data DATASET [--frames N] [--crop-fov-deg 120] [--overlap 10]
                                     [--work /tmp/pipemap-peer] [--out benchmarks/results/peer-colmap.json]

pycolmap (optional: `pip install pycolmap`) has no camera model past 90 deg colatitude (its fisheye
models return wrong rays beyond it), so the peer sees the central `--crop-fov-deg` of each fisheye
frame resampled to an exact equidistant view: every output pixel at radius r from the centre is the
bearing with colatitude r / f (f = the fisheye's k1, its pixels per radian at the centre, so the
centre keeps its resolution), projected into the frame with pipemap's own camera model and read by
cv2.remap. That view is exactly COLMAP's OPENCV_FISHEYE with k1..k4 = 0, given to pycolmap as known
and fixed intrinsics with a mask of the valid disc, so neither side estimates its calibration.
Resampling (rather than fitting an OPENCV_FISHEYE to the polynomial and masking the raw frame) keeps the
model exact: the fisheye paper's polynomial has a theta^4 term that the odd Kannala-Brandt series
cannot represent. An equidistant view (rather than a perspective one) keeps the scale nearly uniform
out to the crop's edge, where a 120 deg perspective view would stretch patches 4x radially.

Fair accounting: both sides read the same first N PNG frames; the peer's time counts the resampling
and PNG writing of its view, SIFT extraction, sequential matching with geometric verification
(`--overlap` neighbours, quadratic overlap; loop detection off: it needs a vocabulary tree file, and
the default sequence does not revisit a place) and incremental mapping, all on the same cores as
`pipemap run` (a child process, the CLI's own timing). Registered images are those of the largest
model; the ATE of each side is over its own poses (pipemap: keyframes; pycolmap: registered images)
and over the frames both placed, after a Sim(3) (Umeyama) alignment to ground_truth/poses.tum.
Writes the JSON to --out and prints a summary.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

from pipemap.dataset import load_dataset
from pipemap.errors import PipemapError
from pipemap.evaluation import associate, ate, evaluate, path_length
from pipemap.output import atomic_write_text
from pipemap.trajectory import Trajectory, read_tum, write_tum

MASK_MARGIN_PX = 4  # keep SIFT off the disc's rim, where the resampled edge makes false corners


def equidistant_view(camera, fov_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[float]]:
    """Remap tables (map_x, map_y) from an equidistant view of the central `fov_deg` into the frame,
    the view's valid-disc mask (uint8, 255 inside) and its OPENCV_FISHEYE parameters for COLMAP."""
    f = float(camera.params[0])  # polynomial k1 / Kannala-Brandt fx: pixels per radian at the centre
    if camera.model == "kannala_brandt":
        f = float(np.sqrt(camera.params[0] * camera.params[1]))
    half = np.radians(fov_deg) / 2.0
    radius = f * half
    size = 2 * int(np.ceil(radius)) + 1
    c = (size - 1) / 2.0
    v, u = np.mgrid[0:size, 0:size].astype(np.float64)
    x, y = u - c, v - c
    theta = np.hypot(x, y) / f
    phi = np.arctan2(y, x)
    bearing = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    pixels, valid = camera.project(bearing)
    valid &= theta <= half
    map_x = np.where(valid, pixels[..., 0], -1).astype(np.float32)
    map_y = np.where(valid, pixels[..., 1], -1).astype(np.float32)
    mask = (np.hypot(x, y) <= radius - MASK_MARGIN_PX) & valid
    # COLMAP puts the centre of the top-left pixel at (0.5, 0.5); pipemap (formats.md) at (0, 0).
    params = [f, f, c + 0.5, c + 0.5, 0.0, 0.0, 0.0, 0.0]
    return map_x, map_y, (mask * 255).astype(np.uint8), params


def subset_dataset(data: Path, frames: int, work: Path) -> Path:
    """`data` itself, or a copy of its first `frames` frames (links) with the same camera and ground truth."""
    ds = load_dataset(data)
    if frames >= len(ds):
        return data
    if ds.image_paths is None:
        raise PipemapError("--frames needs an image-folder dataset, not a video", ds.yaml_path)
    root = work / f"{data.name}-first{frames}"
    if (root / "dataset.yaml").exists() and len(list((root / "images").iterdir())) == frames:
        return root
    shutil.rmtree(root, ignore_errors=True)
    (root / "images").mkdir(parents=True)
    for p in ds.image_paths[:frames]:
        (root / "images" / p.name).symlink_to(p.resolve())
    spec = yaml.safe_load(ds.yaml_path.read_text())
    spec["images"] = f"images/*{ds.image_paths[0].suffix}"
    (root / "dataset.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    if ds.has_gain_mask:
        mask = root / ds.gain_mask_path.relative_to(ds.root)
        mask.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ds.gain_mask_path, mask)
    shutil.copytree(ds.ground_truth_dir, root / "ground_truth")
    return root


def write_view_frames(ds, frames: int, fov_deg: float, image_dir: Path) -> tuple[Path, list[float], int]:
    """The peer's input: each frame (gain-corrected as pipemap reads it) resampled to the equidistant view."""
    map_x, map_y, mask, params = equidistant_view(ds.camera, fov_deg)
    image_dir.mkdir(parents=True)
    mask_path = image_dir.parent / "mask.png"
    cv2.imwrite(str(mask_path), mask)
    for frame in ds.frames(0, frames):
        grey = np.clip(frame.image, 0, 255).astype(np.uint8)
        view = cv2.remap(grey, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        cv2.imwrite(str(image_dir / f"{frame.index:06d}.png"), view, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return mask_path, params, mask.shape[0]


def cpu_seconds() -> float:
    """User + system CPU time of this process, all threads: less sensitive than wall time to a busy machine."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run_colmap(args, ds, frames: int, work: Path) -> dict:
    import pycolmap

    pycolmap.logging.minloglevel = pycolmap.logging.Level.WARNING.value
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    image_dir, db = work / "images", work / "database.db"
    seconds, cpu = {}, {}
    t0, c0 = time.perf_counter(), cpu_seconds()
    mask_path, params, size = write_view_frames(ds, frames, args.crop_fov_deg, image_dir)
    seconds["view"], cpu["view"] = time.perf_counter() - t0, cpu_seconds() - c0

    t, c = time.perf_counter(), cpu_seconds()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "OPENCV_FISHEYE"
    reader.camera_params = ",".join(f"{p:.9g}" for p in params)
    reader.camera_mask_path = mask_path
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = args.threads
    extraction.sift.max_num_features = args.max_features
    pycolmap.extract_features(db, image_dir, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    seconds["extraction"], cpu["extraction"] = time.perf_counter() - t, cpu_seconds() - c

    t, c = time.perf_counter(), cpu_seconds()
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = args.overlap
    pairing.loop_detection = False
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = args.threads
    pycolmap.match_sequential(db, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
    seconds["matching"], cpu["matching"] = time.perf_counter() - t, cpu_seconds() - c

    t, c = time.perf_counter(), cpu_seconds()
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = args.threads
    options.random_seed = args.seed
    options.ba_refine_focal_length = False
    options.ba_refine_principal_point = False
    options.ba_refine_extra_params = False
    options.mapper.abs_pose_refine_focal_length = False
    options.mapper.abs_pose_refine_extra_params = False
    models = pycolmap.incremental_mapping(db, image_dir, work / "sparse", options=options)
    seconds["mapping"], cpu["mapping"] = time.perf_counter() - t, cpu_seconds() - c
    seconds["total"], cpu["total"] = time.perf_counter() - t0, cpu_seconds() - c0

    sizes = {k: m.num_reg_images() for k, m in models.items()}
    entry = {"view_size_px": size, "camera_params_opencv_fisheye": params, "models": len(models),
             "registered_per_model": list(sizes.values()),
             "seconds": {k: round(v, 2) for k, v in seconds.items()},
             "cpu_seconds": {k: round(v, 2) for k, v in cpu.items()}}
    if not models:
        return entry | {"registered_images": 0, "trajectory": None}
    best = models[max(sizes, key=sizes.get)]
    index, T_wc = [], []
    for image in best.images.values():
        if not image.has_pose:
            continue
        T = np.eye(4)
        T[:3, :4] = image.cam_from_world().inverse().matrix()
        index.append(int(Path(image.name).stem))
        T_wc.append(T)
    order = np.argsort(index)
    traj = Trajectory.from_matrices(np.asarray(index, float)[order] / ds.fps, np.asarray(T_wc)[order])
    result = work / "result"
    result.mkdir()
    write_tum(result / "trajectory.tum", traj,
              header=f"pycolmap {pycolmap.__version__} incremental SfM (arbitrary scale)")
    return entry | {"registered_images": len(index), "points": best.num_points3D(),
                    "mean_reprojection_error_px": round(float(best.compute_mean_reprojection_error()), 3),
                    "trajectory": str(result / "trajectory.tum")}


def run_pipemap(data: Path, out: Path) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pipemap", "run", str(data), "--out", str(out)],
                          capture_output=True, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"pipemap run failed on {data}: {proc.stderr.strip() or proc.stdout.strip()}")
    run = json.loads((out / "run.json").read_text())
    return {"wall_s": round(wall, 2),
            "cpu_s": round(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, 2),
            "seconds": run["seconds"], "keyframes": run["keyframes"], "trajectory": str(out / "trajectory.tum")}


def accuracy(trajectory: str, data: Path) -> dict:
    """ATE after Sim(3) and rigid alignment over the side's own poses (pipemap.evaluation, metrics.json)."""
    m = evaluate(Path(trajectory).parent, data)
    return {"poses": m.associated_poses, "ate_sim3_m": m.ate_sim3.rmse,
            "ate_sim3_pct_of_path": m.ate_rmse_pct(m.ate_sim3),
            "ate_rigid_m": m.ate_rigid.rmse, "sim3_scale": m.ate_sim3.scale}


def common_ate(a: str, b: str, gt: Trajectory) -> dict | None:
    """Sim(3) ATE of both sides over the frames both placed, so neither gains from its choice of poses."""
    ta, tb = read_tum(a), read_tum(b)
    ia, ib = associate(ta.timestamps, tb.timestamps)
    if len(ia) < 3:
        return None
    ga, gi = associate(ta.timestamps[ia], gt.timestamps)
    gp = gt.positions[gi]
    return {"frames": len(ga), "gt_path_m": path_length(gp),
            "pipemap_ate_sim3_m": ate(ta.positions[ia][ga], gp, with_scale=True).rmse,
            "pycolmap_ate_sim3_m": ate(tb.positions[ib][ga], gp, with_scale=True).rmse}


def ratio(a, b):
    return None if a in (None, 0) or b is None else round(b / a, 3)


def main() -> None:
    try:
        compare()
    except PipemapError as exc:
        raise SystemExit(f"peer_colmap: {exc}") from None


def compare() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="a pipemap dataset folder with ground_truth/")
    ap.add_argument("--frames", type=int, default=None, help="the first N frames (default: all)")
    ap.add_argument("--crop-fov-deg", type=float, default=120.0, help="field of view of the peer's equidistant view")
    ap.add_argument("--overlap", type=int, default=10, help="sequential matching: neighbours per image")
    ap.add_argument("--max-features", type=int, default=8192, help="SIFT features per image (COLMAP's default 8192)")
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", default="/tmp/pipemap-peer")
    ap.add_argument("--skip-pipemap", action="store_true", help="time only the peer")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "peer-colmap.json"))
    args = ap.parse_args()

    data = Path(args.data)
    ds = load_dataset(data)
    if args.frames is not None and args.frames < 2:
        raise PipemapError(f"must be at least 2, got {args.frames}", "--frames")
    frames = len(ds) if args.frames is None else min(args.frames, len(ds))
    if not 0 < args.crop_fov_deg < 180:
        raise PipemapError("must lie in (0, 180) degrees: pycolmap has no model past 90 deg, "
                           f"got {args.crop_fov_deg:g}",
                           "--crop-fov-deg")
    if np.radians(args.crop_fov_deg) / 2 > ds.camera.max_theta:
        raise PipemapError(f"--crop-fov-deg {args.crop_fov_deg:g} exceeds the camera's field of view "
                           f"({2 * ds.camera.max_theta_deg:g} deg)", ds.yaml_path)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    same = subset_dataset(data, frames, work)
    result: dict = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                "load_average_at_start": list(os.getloadavg())},
                    "dataset": str(data.resolve()), "frames": frames, "size": f"{ds.camera.width}x{ds.camera.height}",
                    "crop_fov_deg": args.crop_fov_deg, "overlap": args.overlap, "max_features": args.max_features,
                    "threads": args.threads}
    try:
        import pycolmap
        result["pycolmap_version"] = pycolmap.__version__
    except ImportError:
        result["pycolmap"] = {"not_run": "pycolmap is not installed (pip install pycolmap)"}
    else:
        try:
            peer = run_colmap(args, ds, frames, work / f"colmap-{same.name}-{args.crop_fov_deg:g}")
        except Exception as exc:  # the peer failing is a result to report, not a reason to lose pipemap's figures
            result["pycolmap"] = {"not_run": f"pycolmap failed: {type(exc).__name__}: {exc}"}
            print(result["pycolmap"]["not_run"], flush=True)
        else:
            peer["wall_s"], peer["cpu_s"] = peer["seconds"]["total"], peer["cpu_seconds"]["total"]
            if peer.get("trajectory"):
                peer["accuracy"] = accuracy(peer["trajectory"], same)
            result["pycolmap"] = peer
            print(f"pycolmap: {peer['registered_images']}/{frames} registered in {peer['models']} model(s), "
                  f"{peer['wall_s']} s ({peer['seconds']})", flush=True)
    if not args.skip_pipemap:
        mine = run_pipemap(same, work / f"pipemap-{same.name}")
        mine["accuracy"] = accuracy(mine["trajectory"], same)
        result["pipemap"] = mine
        print(f"pipemap: {mine['keyframes']} keyframes, {mine['wall_s']} s ({mine['seconds']})", flush=True)
    peer, mine = result.get("pycolmap", {}), result.get("pipemap")
    if mine and peer.get("accuracy"):
        common = common_ate(mine["trajectory"], peer["trajectory"], load_dataset(same).ground_truth_poses())
        result["common_frames"] = common
        result["ratios"] = {
            "speedup_wall": ratio(mine["wall_s"], peer["wall_s"]),
            "speedup_cpu": ratio(mine["cpu_s"], peer["cpu_s"]),
            "ate_sim3_peer_over_pipemap": ratio(mine["accuracy"]["ate_sim3_m"], peer["accuracy"]["ate_sim3_m"]),
            "ate_sim3_common_peer_over_pipemap":
                None if common is None else ratio(common["pipemap_ate_sim3_m"], common["pycolmap_ate_sim3_m"]),
            "registered_fraction": round(peer["registered_images"] / frames, 3),
        }
        print(f"ratios (pycolmap / pipemap): {result['ratios']}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, json.dumps(result, indent=2, default=float) + "\n")
    print(f"written {out}")


if __name__ == "__main__":
    main()
