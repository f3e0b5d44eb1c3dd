"""Appearance-map speed and fidelity, and the wall time of `pipemap demo`.

    python benchmarks/bench_appearance.py [--frames 120] [--size 640x480] [--demo] [--screenshot]

1. Renders demo-loop (through its first tee, frames 2 cm apart) and builds the appearance map
   from the ground-truth poses and pieces: grid points projected per second, map points, and the
   correlation of the map's grey levels with the simulator's baked wall texture (both high-passed),
   also for poses shifted 3 cm along the path (a misregistered map must score clearly lower).
2. --demo: runs the demo at its default size (640x480, the whole loop) and reports its wall time
   per stage and its figures (the demo must finish within 5 minutes on 2 cores).
3. --screenshot: with --demo, a headless chromium screenshot of report.html, when chromium is installed.

Prints the figures and writes benchmarks/results/appearance.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from pipemap.config import AppearanceSettings
from pipemap.dataset import load_dataset
from pipemap.mapping import WallPiece, build_appearance
from pipemap.sim.simulate import plan, simulate
from pipemap.sim.texture import WallTexture

RESULTS = Path(__file__).parent / "results" / "appearance.json"


def high_pass(values: np.ndarray, seen: np.ndarray, sigma: float = 6.0) -> np.ndarray:
    x = np.where(seen, values, 0).astype(np.float32)
    w = seen.astype(np.float32)
    return x - cv2.GaussianBlur(x, (0, 0), sigma) / np.maximum(cv2.GaussianBlur(w, (0, 0), sigma), 1e-6)


def texture_correlation(amap, scene, texture) -> float:
    a, b = [], []
    for pm, pipe in zip(amap.pieces, scene.pipes):
        seen = pm.seen
        if not seen.any():
            continue
        surf = texture.surface(pipe.id, pipe.extend_start + pipe.length + pipe.extend_end, 2 * np.pi * scene.radius)
        hh, ph = np.meshgrid(pm.grid.h, pm.grid.phi, indexing="ij")
        albedo = surf.sample(hh + pipe.extend_start, -ph * scene.radius, 0.004)
        a.append(high_pass(pm.intensity, seen)[seen])
        b.append(high_pass(albedo, seen)[seen])
    return float(np.corrcoef(np.concatenate(a), np.concatenate(b))[0, 1])


def bench_map(frames: int, width: int, height: int, tmp: Path) -> dict:
    spec = dict(width=width, height=height, frames=frames, seed=0, spacing_m=0.02)
    root = simulate("demo-loop", tmp / "loop", **spec)
    ds = load_dataset(root)
    setup = plan("demo-loop", **spec).setup
    texture = WallTexture(0, setup.appearance.mm_per_px, setup.appearance.texture_style)
    net = ds.network()
    pieces = [WallPiece(s.id, s.start, s.end, net.radius_m, [0, 0, 1.0], not s.id.startswith("B"))
              for s in net.segments]
    gt = ds.ground_truth_poses()
    T = gt.matrices()
    idx = np.arange(len(gt))
    amap = build_appearance(ds, idx, T, pieces, AppearanceSettings())
    shifted = T.copy()
    tangent = np.gradient(T[:, :3, 3], axis=0)
    shifted[:, :3, 3] += 0.03 * tangent / np.linalg.norm(tangent, axis=1, keepdims=True)
    amap_shifted = build_appearance(ds, idx, shifted, pieces, AppearanceSettings())
    points, _ = amap.points()
    return {
        "preset": "demo-loop", "size": f"{width}x{height}", "keyframes": amap.keyframes,
        "spacing_m": AppearanceSettings().spacing_m, "map_points": int(len(points)),
        "projections": amap.projections, "samples": amap.samples, "seconds": round(amap.seconds, 3),
        "points_per_second": round(amap.points_per_second),
        "seconds_per_keyframe": round(amap.seconds / amap.keyframes, 4),
        "texture_correlation": round(texture_correlation(amap, setup.scene, texture), 3),
        "texture_correlation_shifted_3cm": round(texture_correlation(amap_shifted, setup.scene, texture), 3),
    }


def bench_demo(tmp: Path, screenshot: bool) -> dict:
    from pipemap.demo import run_demo

    t0 = time.perf_counter()
    s = run_demo(tmp / "demo")
    wall = time.perf_counter() - t0
    out = {"wall_s": round(wall, 1), "stages_s": {k: round(v, 1) for k, v in s.seconds.items()},
           "frames": s.frames, "keyframes": s.keyframes, "path_length_error_pct": s.path_length_error_pct,
           "ate_rmse_m": s.ate_rmse_m, "tee_errors": s.tee_errors, "appearance_points": s.appearance_points,
           "under_5_minutes": wall < 300}
    run = json.loads((s.result_dir / "run.json").read_text())
    out["appearance"] = run.get("appearance")
    if screenshot:
        out["screenshot"] = take_screenshot(s.report, RESULTS.parent / "report.png")
    return out


def take_screenshot(html: Path, png: Path) -> str:
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        return "skipped: chromium is not installed"
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--window-size=1200,2400",
           f"--screenshot={png}", html.resolve().as_uri()]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    return str(png) if r.returncode == 0 and png.exists() else f"failed: {r.stderr.strip().splitlines()[-1:]}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--demo", action="store_true", help="also time `pipemap demo` at its default size")
    ap.add_argument("--screenshot", action="store_true", help="with --demo: headless chromium screenshot of the report")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        result = {"benchmark": "appearance map", "cores": os.cpu_count(), "load_average": os.getloadavg(),
                  "python": platform.python_version(), "map": bench_map(args.frames, width, height, Path(tmp))}
        print(json.dumps(result["map"], indent=1))
        if args.demo:
            result["demo"] = bench_demo(Path(tmp), args.screenshot)
            print(json.dumps(result["demo"], indent=1))
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=1) + "\n")
    print(f"written {RESULTS}")


if __name__ == "__main__":
    main()
