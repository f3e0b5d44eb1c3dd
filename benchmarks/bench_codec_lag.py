"""How far lossy video moves wall features: anchor matches on decoded frames against the same matches on the
frames before encoding (the image-conditions issue: H.264 footage maps short).

    python benchmarks/bench_codec_lag.py [--frames 200] [--crf 28] [--preset fisheye-straight] [--seed 1]
                                         [--gap 7] [--blur 0] [--smooth 0] [--route ROUTE] [--skip 0]
                                         [--data /tmp/pipemap-bench-lag]

Renders the preset's first frames as clean PNGs (cached under --data), encodes them with libx264 at --crf (or,
with --blur S, replaces the codec by a Gaussian blur of sigma S px plus independent noise, as a control), and
for corners taken every --gap frames tracks each one over the next --gap frames with the front end's anchor match
(frontend/anchor.py: the patch where the corner was first seen, warped into the later frame) on the lighting-
flattened images, four ways: clean patch into clean frame (the reference), clean into decoded, decoded into
clean and decoded into decoded; --smooth S blurs every frame, clean and decoded, by sigma S px first, as
`frontend.smooth_sigma_px` does; --route and --skip N take the frames after the route's first N (the reverse leg of
fisheye-straight's forward-reverse route: `--route forward-reverse --skip 480`). Prints and writes
(benchmarks/results/codec_lag.json) the mean displacement of each against the reference along the direction of
motion, per frame gap: negative = behind, towards where the feature was. The pipeline's tracks are decoded-into-decoded.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path

import av
import cv2
import numpy as np

from pipemap.dataset import load_dataset
from pipemap.frontend.anchor import anchor_templates, refine_to_anchors
from pipemap.frontend.harris import flatten_lighting
from pipemap.sim.simulate import simulate

PATCH = 11
WAYS = ("clean->decoded", "decoded->clean", "decoded->decoded")


def clean_frames(args) -> list[np.ndarray]:
    root = Path(args.data) / f"{args.preset}-{args.route or 'default'}-{args.skip + args.frames}-s{args.seed}"
    if not (root / "dataset.yaml").exists():
        simulate(args.preset, root, width=640, height=480, frames=args.skip + args.frames, seed=args.seed, workers=2,
                 route=args.route)
    return [f.image.astype(np.uint8) for f in load_dataset(root).frames()][args.skip:]


def degraded(frames: list[np.ndarray], args) -> list[np.ndarray]:
    if args.blur > 0:
        rng = np.random.default_rng(args.seed)
        return [np.clip(np.rint(cv2.GaussianBlur(f.astype(np.float32), (0, 0), args.blur)
                                + rng.normal(0.0, 2.0, f.shape)), 0, 255).astype(np.uint8) for f in frames]
    path = Path(args.data) / f"lag-crf{args.crf:g}-{args.route or 'default'}-{args.skip}.mp4"
    h, w = frames[0].shape
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=8)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        stream.options = {"crf": f"{args.crf:g}", "preset": "medium", "threads": "1"}
        for f in frames:
            out.mux(stream.encode(av.VideoFrame.from_ndarray(cv2.cvtColor(f, cv2.COLOR_GRAY2RGB), format="rgb24")))
        out.mux(stream.encode())
    with av.open(str(path)) as src:
        return [fr.to_ndarray(format="gray") for fr in src.decode(video=0)]


def flattened(image: np.ndarray, smooth: float) -> np.ndarray:
    image = image.astype(np.float32)
    if smooth > 0:
        image = cv2.GaussianBlur(image, (0, 0), smooth)
    return flatten_lighting(image, 4.0, 0.0)[0]


def measure(clean: list[np.ndarray], coded: list[np.ndarray], gap: int, smooth: float = 0.0) -> dict:
    h, w = clean[0].shape
    lag = {(way, j): [] for way in WAYS for j in range(1, gap + 1)}
    for a in range(10, len(clean) - gap - 1, gap):
        images = {"clean": [flattened(clean[a + j], smooth) for j in range(gap + 1)],
                  "decoded": [flattened(coded[a + j], smooth) for j in range(gap + 1)]}
        start = cv2.goodFeaturesToTrack(clean[a], 400, 0.01, 8).reshape(-1, 2)
        r = np.hypot(start[:, 0] - w / 2, start[:, 1] - h / 2)
        start = start[(r > 70) & (r < 210)]  # the wall ring of the fisheye, away from the dark far end and the rim
        anchors = {s: anchor_templates(images[s][0], start, PATCH) for s in images}
        now = start.copy()
        for j in range(1, gap + 1):
            guess, _, _ = cv2.calcOpticalFlowPyrLK(clean[a + j - 1], clean[a + j], now.astype(np.float32), None,
                                                   winSize=(21, 21))
            found = {}
            for s1 in images:
                for s2 in images:
                    found[s1, s2] = refine_to_anchors(images[s2][j], anchors[s1], guess, PATCH, iterations=10,
                                                      max_shift_px=3)
            for s in images:  # the warps carry on along each way's own track
                anchors[s] = found[s, s][2]
            reference = found["clean", "clean"][1]
            now = reference
            d = reference - start
            along = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
            ok = np.all([v[0] for v in found.values()], axis=0)
            for way in WAYS:
                s1, s2 = way.split("->")
                lag[way, j].append((((found[s1, s2][1] - reference) * along).sum(axis=1))[ok])
    return {way: {j: float(np.concatenate(lag[way, j]).mean()) for j in range(1, gap + 1)} for way in WAYS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--crf", type=float, default=28.0)
    ap.add_argument("--gap", type=int, default=7, help="frames each corner is followed from its anchor frame")
    ap.add_argument("--blur", type=float, default=0.0, help="a Gaussian blur of this sigma (px) plus noise instead "
                    "of the codec (a control)")
    ap.add_argument("--smooth", type=float, default=0.0, help="blur every frame by this sigma (px) before the "
                    "matches, as frontend.smooth_sigma_px does")
    ap.add_argument("--preset", default="fisheye-straight")
    ap.add_argument("--route", default=None, help="the preset's route (default: its first)")
    ap.add_argument("--skip", type=int, default=0, help="leave out the route's first N frames")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--data", default="/tmp/pipemap-bench-lag")
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "codec_lag.json"))
    args = ap.parse_args()
    Path(args.data).mkdir(parents=True, exist_ok=True)
    clean = clean_frames(args)
    lag = measure(clean, degraded(clean, args), args.gap, args.smooth)
    shown = [j for j in (1, 2, 3, 5, 7, 10, 14, 20, 28, 40) if j <= args.gap]
    label = f"blur {args.blur:g} px + noise" if args.blur > 0 else f"H.264 CRF {args.crf:g}"
    label += f", frames smoothed {args.smooth:g} px" if args.smooth > 0 else ""
    print(f"{label}: mean displacement along the motion against clean->clean (px; negative = behind)")
    print("gap (frames)    " + " ".join(f"{j:>8d}" for j in shown))
    for way in WAYS:
        print(f"{way:<16s}" + " ".join(f"{lag[way][j]:+8.4f}" for j in shown))
    summary = {"benchmark": "codec_lag", "machine": platform.platform(), "cpus": os.cpu_count(),
               "degradation": label, "smooth_px": args.smooth, "preset": args.preset, "route": args.route,
               "skip": args.skip, "frames": len(clean), "seed": args.seed,
               "lag_px": {way: {str(j): v for j, v in lag[way].items()} for way in WAYS}}
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
