"""The results contract shared by every method: one run.json record (docs/formats.md, `pipemap-run/2`).

Every method writes the same leading keys, so that the report, the self-checks' readers, batch summaries
and other tools read any result alike; what only one method knows follows under its own keys.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipemap.output import atomic_write_text

RUN_FORMAT = "pipemap-run/2"
TRAJECTORY_KINDS = ("keyframes", "frames")


def run_record(method: str, dataset, settings, *, frames: int, keyframes: int, trajectory: str, mount: dict | None,
               footage: dict, problems: list[str], quality: dict | None, seconds: dict, **details) -> dict:
    """run.json of one run. `trajectory`: which frames trajectory.tum holds (keyframes or all frames);
    `mount`: the camera's mount on the robot where the method estimates it; `problems`: one sentence each,
    what the run could not do; `details`: the method's own keys, after the common ones."""
    from pipemap import __version__

    if trajectory not in TRAJECTORY_KINDS:
        raise ValueError(f"trajectory must be one of {TRAJECTORY_KINDS}, got {trajectory!r}")
    record = {
        "format": RUN_FORMAT,
        "version": __version__,
        "method": method,
        "input": str(dataset.root),
        "camera": dataset.camera.to_dict(),
        "pipe_radius_m": dataset.radius_m,
        "trajectory": trajectory,
        "frames": int(frames),
        "keyframes": int(keyframes),
        "mount": mount,
        "footage": footage,
        "problems": list(problems),
        "quality": quality,
    }
    clash = set(record) & set(details)
    if clash:
        raise ValueError(f"method details repeat common run.json keys: {sorted(clash)}")
    record.update(details)
    record["settings"] = settings.recorded()
    record["seconds"] = {k: round(float(v), 3) for k, v in seconds.items()}
    return record


def write_run_json(folder: Path, record: dict) -> None:
    atomic_write_text(Path(folder) / "run.json", json.dumps(record, indent=2, default=_json_default) + "\n")


# run.json keys that hold wall times or rates, which differ from one run of the same input to the next
TIMING_KEYS = ("seconds", "time_s", "points_per_second")


def result_differences(a: Path, b: Path, ignore: tuple[str, ...] = TIMING_KEYS) -> list[str]:
    """What differs between two result folders: files present in one only or not byte-identical, except that
    the JSON files are compared as data with the keys in `ignore` left out, naming each differing key's path."""
    a, b = Path(a), Path(b)
    names = sorted({p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file()}
                   | {p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file()})
    found = []
    for name in names:
        fa, fb = a / name, b / name
        if not (fa.is_file() and fb.is_file()):
            found.append(f"{name}: only in {a if fa.is_file() else b}")
        elif name.endswith(".json"):
            found += [f"{name}: {key}" for key in _json_paths(json.loads(fa.read_text()), json.loads(fb.read_text()),
                                                             "", ignore)]
        elif fa.read_bytes() != fb.read_bytes():
            found.append(name)
    return found


def _json_paths(x, y, where: str, ignore) -> list[str]:
    if isinstance(x, dict) and isinstance(y, dict):
        return [p for k in sorted(set(x) | set(y)) if k not in ignore
                for p in (_json_paths(x.get(k), y.get(k), f"{where}.{k}" if where else k, ignore)
                          if k in x and k in y else [f"{where}.{k}" if where else k])]
    if isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
        return [p for i, (u, v) in enumerate(zip(x, y)) for p in _json_paths(u, v, f"{where}[{i}]", ignore)]
    both_nan = isinstance(x, float) and isinstance(y, float) and x != x and y != y  # run.json writes NaN
    return [] if x == y or both_nan else [where]


def _json_default(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, float) and not np.isfinite(v):
        return None
    raise TypeError(type(v))


__all__ = ["RUN_FORMAT", "TRAJECTORY_KINDS", "TIMING_KEYS", "run_record", "write_run_json", "result_differences"]
