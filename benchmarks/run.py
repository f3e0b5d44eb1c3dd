"""The benchmark suite: runs the bench scripts as child processes, collects their JSON and writes
suite-<suite>.json and suite-<suite>.md (Markdown tables) under --out.

    python benchmarks/run.py --suite quick|full [--data /tmp/pipemap-bench] [--out benchmarks/results]

quick (about 10 minutes on 2 idle cores; 17 minutes measured under a load average of 4-6): the
fisheye pipeline on paper-loop route A at 640x480 and its first half (320x240 is too coarse for the
pipeline to map the loop), one Table 2 case per straight-pipe method at wider frame spacing, the
pycolmap peer on the first 150 frames of that render, bench_appearance at its defaults.
full (the acceptance sizes; hours on 2 cores): paper-loop routes A and B (B also without loop
closure) and the first half of A at 640x480 and at 1280x960, the Table 2 cases at the report's
frame counts (sparse) and the dense benchmark's spacing, and the peer on the first 500 frames at
640x480 (one straight side and the tee T1), bench_appearance with --demo.

Each step's JSON is copied to <out>/suite-<suite>/<name>.json. A piece that cannot run (a bench
script absent, pycolmap not installed, a step that failed) is reported as "not run: <why>" in the
tables; the suite itself does not stop.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from suite_tables import goals, markdown, not_run  # noqa: E402

from pipemap.output import atomic_write_text  # noqa: E402

HERE = Path(__file__).parent
RESULTS = HERE / "results"


@dataclass
class Step:
    name: str  # the result's name in the tables, e.g. "network-640x480"
    script: str  # a file in benchmarks/
    args: list[str]
    writes: str  # the JSON the script writes: "{out}" means the step's --out, else a path under benchmarks/
    needs: list[str] = field(default_factory=list)  # importable modules, e.g. pycolmap


def network(width: int, height: int, routes: list[str]) -> Step:
    return Step(f"network-{width}x{height}", "bench_network.py",
                ["--width", str(width), "--height", str(height), "--routes", *routes, "--half",
                 "--data", "{data}", "--out", "{data}/runs"], f"results/network-{width}x{height}.json")


def peer(width: int, height: int, frames: int) -> Step:
    return Step("peer-colmap", "peer_colmap.py",
                ["--data", f"{{data}}/paper-loop-A-{width}x{height}", "--frames", str(frames),
                 "--work", "{data}/peer", "--out", "{out}"], "{out}", needs=["pycolmap"])


SUITES = {
    "quick": [
        network(640, 480, ["A"]),
        Step("dense", "bench_dense.py", ["--data", "{data}/straight", "--cases", "6in-forward",
                                         "--methods", "dense-hybrid", "--spacing-6in", "0.02", "--out", "{out}"],
             "{out}"),
        Step("sparse", "bench_sparse.py", ["--data", "{data}/straight", "--cases", "6in-forward",
                                           "--spacing-6in", "0.02", "--out", "{out}"], "{out}"),
        peer(640, 480, 150),
        Step("appearance", "bench_appearance.py", [], "results/appearance.json"),
    ],
    "full": [
        network(640, 480, ["A", "B"]),
        network(1280, 960, ["A", "B"]),
        Step("dense", "bench_dense.py", ["--data", "{data}/straight", "--out", "{out}"], "{out}"),
        Step("sparse", "bench_sparse.py", ["--data", "{data}/straight", "--out", "{out}"], "{out}"),
        peer(640, 480, 500),
        Step("appearance", "bench_appearance.py", ["--demo"], "results/appearance.json"),
    ],
}


def peer_dataset(step: Step, data: Path, log) -> tuple[str, str | None]:
    """The peer reads the first N frames of route A: bench_network's full render when it is cached,
    else a render of just those frames. Returns (dataset folder, why it is missing or None)."""
    root = Path(step.args[step.args.index("--data") + 1].format(data=data))
    frames = step.args[step.args.index("--frames") + 1]
    if (root / "dataset.yaml").exists():
        return str(root), None
    width, height = root.name.rsplit("-", 1)[1].split("x")
    part = root.with_name(f"{root.name}-{frames}")  # bench_network's name for a first-N render
    if (part / "dataset.yaml").exists():
        return str(part), None
    shutil.rmtree(part, ignore_errors=True)
    cmd = [sys.executable, "-m", "pipemap", "simulate", "paper-loop", "--out", str(part), "--width", width,
           "--height", height, "--frames", frames, "--route", "A", "--workers", str(os.cpu_count() or 1)]
    print("$ " + " ".join(cmd), file=log, flush=True)
    proc = subprocess.run(cmd, stdout=log, stderr=subprocess.PIPE, text=True)
    if proc.returncode != 0:
        return str(part), f"rendering the peer's frames failed: {last_line(proc.stderr)}"
    return str(part), None


def last_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1].strip() if lines else "no message"


def run_step(step: Step, data: Path, step_out: Path, log) -> tuple[dict, dict]:
    """Run one bench script; return (its JSON or not_run(why), the step's status record)."""
    script = HERE / step.script
    record = {"name": step.name, "script": step.script}
    if not script.exists():
        why = f"benchmarks/{step.script} not found"
        return not_run(why), record | {"status": f"not run: {why}"}
    for module in step.needs:
        if importlib.util.find_spec(module) is None:
            why = f"{module} is not installed (pip install {module})"
            return not_run(why), record | {"status": f"not run: {why}"}
    args = [a.format(data=data, out=step_out) for a in step.args]
    if step.name == "peer-colmap":
        args[args.index("--data") + 1], why = peer_dataset(step, data, log)
        if why:
            return not_run(why), record | {"status": f"not run: {why}"}
    cmd = [sys.executable, str(script), *args]
    written = step_out if step.writes == "{out}" else HERE / step.writes
    record["command"] = "python " + " ".join([f"benchmarks/{step.script}", *args])
    print(f"\n$ {record['command']}", file=log, flush=True)
    start = time.time()
    t = time.perf_counter()
    proc = subprocess.run(cmd, stdout=log, stderr=subprocess.PIPE, text=True)
    record["seconds"] = round(time.perf_counter() - t, 1)
    log.write(proc.stderr)
    if proc.returncode != 0:
        why = f"failed (exit {proc.returncode}): {last_line(proc.stderr)}"
        return not_run(why), record | {"status": why}
    if not written.exists() or written.stat().st_mtime < start:
        why = f"finished but wrote no {written.name}"
        return not_run(why), record | {"status": why}
    try:
        result = json.loads(written.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        why = f"unreadable {written.name}: {exc}"
        return not_run(why), record | {"status": why}
    if written != step_out:
        shutil.copy(written, step_out)
    return result, record | {"status": "ok", "json": str(step_out)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--suite", choices=sorted(SUITES), required=True)
    ap.add_argument("--data", default="/tmp/pipemap-bench", help="renders are cached here between runs")
    ap.add_argument("--out", default=str(RESULTS), help="folder for suite-<suite>.json/.md and the steps' JSON")
    ap.add_argument("--only", nargs="+", help="run only these steps (by name); the others are reported as not run")
    args = ap.parse_args()

    data, out = Path(args.data).resolve(), Path(args.out).resolve()
    steps_out = out / f"suite-{args.suite}"
    steps_out.mkdir(parents=True, exist_ok=True)
    data.mkdir(parents=True, exist_ok=True)
    machine = {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform(),
               "load average at start": " ".join(f"{x:.2f}" for x in os.getloadavg())}
    results, records = {}, []
    started = time.perf_counter()
    with open(steps_out / "log.txt", "w") as log:
        for step in SUITES[args.suite]:
            if args.only and step.name not in args.only:
                why = "left out by --only"
                results[step.name], record = not_run(why), {"name": step.name, "status": f"not run: {why}"}
            else:
                print(f"[{time.perf_counter() - started:7.0f} s] {step.name} ...", flush=True)
                results[step.name], record = run_step(step, data, steps_out / f"{step.name}.json", log)
            records.append(record)
            print(f"[{time.perf_counter() - started:7.0f} s] {step.name}: {record['status']}", flush=True)
    machine["suite wall s"] = round(time.perf_counter() - started, 1)
    text = markdown(args.suite, results, records, machine)
    suite = {"suite": args.suite, "machine": machine, "goals": goals(results), "steps": records, "results": results}
    atomic_write_text(out / f"suite-{args.suite}.json", json.dumps(suite, indent=2, default=float) + "\n")
    atomic_write_text(out / f"suite-{args.suite}.md", text)
    print(text)
    print(f"written {out / f'suite-{args.suite}.json'} and {out / f'suite-{args.suite}.md'} "
          f"(log: {steps_out / 'log.txt'})")


if __name__ == "__main__":
    main()
