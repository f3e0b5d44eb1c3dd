"""The viewer page of a full result: how long `pipemap report` takes, how big the page is, and how long it takes
to open in headless Chromium (SwiftShader WebGL, no GPU), with its console errors.

    python benchmarks/bench_viewer.py RESULT [--runs 3] [--screenshot docs/viewer.png]

RESULT defaults to the paper-loop route A result at /tmp/pipemap-bench/runs-base/A-640x480. The page is written
to a temporary folder (the result is not touched). "ready" is the page's own time from navigation start to the
end of its drawing (data-ready-ms: 3D view, every wall, plots, tables); "browser" is the whole headless Chromium
process, start to exit, including its own start-up and the DOM dump. Prints the figures and writes
benchmarks/results/viewer.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import tempfile
from pathlib import Path

from pipemap.config import Settings
from pipemap.viewer import write_viewer
from pipemap.viewer.headless import chromium, load_page

RESULTS = Path(__file__).parent / "results" / "viewer.json"
PAPER_LOOP = Path("/tmp/pipemap-bench/runs-base/A-640x480")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("result", nargs="?", type=Path, default=PAPER_LOOP)
    ap.add_argument("--runs", type=int, default=3, help="page loads timed")
    ap.add_argument("--screenshot", type=Path, help="also write a 1400x1300 screenshot here")
    args = ap.parse_args()
    if chromium() is None:
        raise SystemExit("bench_viewer: no chromium on PATH (apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="pipemap-viewer-") as tmp:
        summary = write_viewer(args.result, Path(tmp) / "viewer.html", settings=Settings())
        loads = [load_page(summary.path) for _ in range(args.runs)]
        if args.screenshot:
            load_page(summary.path, screenshot=args.screenshot.resolve(), window="1400,1300")
    ready_ms = [float(x.attributes.get("data-ready-ms", "nan")) for x in loads]
    out = {
        "result": str(args.result), "machine": platform.machine(), "cpus": __import__("os").cpu_count(),
        "write_s": round(summary.seconds, 2), "page_mb": round(summary.bytes / 1e6, 2), "walls": summary.walls,
        "cloud_points": summary.cloud_points, "ready": all(x.ready for x in loads),
        "ready_ms": ready_ms, "ready_ms_median": statistics.median(ready_ms),
        "browser_s": [round(x.seconds, 2) for x in loads],
        "console_errors": sorted({e for x in loads for e in x.errors}),
        "drawn_pixels": [int(x.attributes.get("data-drawn-pixels", 0)) for x in loads],
    }
    print(json.dumps(out, indent=2))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
