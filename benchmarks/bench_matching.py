"""Descriptor matching of one frame pair at the tracker's sizes: corners of image i against those of image j,
candidates within `frontend.max_flow_px`, 11 x 11 grey templates (fisheye paper III-A).

    python benchmarks/bench_matching.py [--corners 1150 1500] [--repeats 50] [--seeds 3]

Most of image i's corners have a noisy copy in image j a few pixels away, the rest of image j's are new; the
corners are spread over a 640 x 480 image. Prints the time per frame pair (one BLAS thread, as in a run) and the
matches found, for `match_descriptors` (the band of corners within reach) and for the matching as it was before
it, every pair's similarity formed and the far ones masked (the same matches); writes
benchmarks/results/matching.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from pipemap.config import Settings
from pipemap.frontend.descriptors import _mutual_ratio, match_descriptors


def frame_pair(n: int, m: int, seed: int):
    rng = np.random.default_rng(seed)
    di = rng.normal(size=(n, 121)).astype(np.float32)
    k = min(n, int(0.87 * n), m)
    dj = rng.normal(size=(m, 121)).astype(np.float32)
    dj[:k] = di[:k] + 0.1 * rng.normal(size=(k, 121)).astype(np.float32)
    di /= np.linalg.norm(di, axis=1, keepdims=True)
    dj /= np.linalg.norm(dj, axis=1, keepdims=True)
    pi = rng.uniform(0, [640, 480], (n, 2)).astype(np.float32)
    pj = rng.uniform(0, [640, 480], (m, 2)).astype(np.float32)
    pj[:k] = pi[:k] + rng.normal(0, 5, (k, 2))
    return di, dj, pi, pj


def every_pair(di, dj, pi, pj, ratio, min_similarity, max_flow_px):
    """The matching as it was before the band: every pair's similarity, the far ones masked 64 rows at a time."""
    sim = di @ dj.T
    far = np.float32(max_flow_px**2)
    for s in range(0, len(pi), 64):
        d2 = np.subtract.outer(pi[s:s + 64, 0], pj[:, 0])
        np.multiply(d2, d2, out=d2)
        dy = np.subtract.outer(pi[s:s + 64, 1], pj[:, 1])
        np.multiply(dy, dy, out=dy)
        d2 += dy
        np.putmask(sim[s:s + 64], d2 > far, -2.0)
    return _mutual_ratio(sim, ratio, min_similarity)


def timed(f, args, repeats: int) -> tuple[float, int]:
    f(*args)
    t = time.perf_counter()
    for _ in range(repeats):
        out = f(*args)
    return (time.perf_counter() - t) / repeats * 1000.0, len(out[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corners", type=int, nargs=2, default=[1150, 1500], help="corners in image i and image j")
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "matching.json")
    args = ap.parse_args()
    f = Settings().frontend
    rows = []
    with threadpool_limits(1, user_api="blas"):
        for seed in range(args.seeds):
            di, dj, pi, pj = frame_pair(*args.corners, seed)
            params = (di, dj, pi, pj, f.match_ratio, f.min_similarity, f.max_flow_px)
            band_ms, band_n = timed(match_descriptors, params, args.repeats)
            full_ms, full_n = timed(every_pair, params, args.repeats)
            rows.append({"seed": seed, "band_ms": round(band_ms, 3), "every_pair_ms": round(full_ms, 3),
                         "matches": band_n, "matches_every_pair": full_n})
            print(f"seed {seed}: {band_ms:6.2f} ms a frame pair ({band_n} matches); every pair masked "
                  f"{full_ms:6.2f} ms ({full_n} matches)", flush=True)
    report = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                          "load_average": list(os.getloadavg())},
              "corners": args.corners, "max_flow_px": f.max_flow_px, "runs": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
