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
    record["settings"] = settings.to_dict()
    record["seconds"] = {k: round(float(v), 3) for k, v in seconds.items()}
    return record


def write_run_json(folder: Path, record: dict) -> None:
    atomic_write_text(Path(folder) / "run.json", json.dumps(record, indent=2, default=_json_default) + "\n")


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


__all__ = ["RUN_FORMAT", "TRAJECTORY_KINDS", "run_record", "write_run_json"]
