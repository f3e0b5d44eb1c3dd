"""The batch's summary table: one row per run, its figures read from the run's own run.json (the results
contract), written as batch.csv (docs/formats.md) and printed."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from pipemap.batch.manifest import BatchRun
from pipemap.output import atomic_write_text

COLUMNS = ("run", "status", "method", "frames", "keyframes", "junctions", "seconds", "quality", "problems",
           "dataset")


def read_result(folder: Path) -> dict | None:
    """run.json of a complete result folder (None: not there or not readable)."""
    try:
        return json.loads((folder / "run.json").read_text())
    except (OSError, ValueError):
        return None


def _junction_count(folder: Path) -> int | str:
    import yaml

    try:
        doc = yaml.safe_load((folder / "junctions.yaml").read_text())
    except (OSError, yaml.YAMLError):
        return ""  # methods for straight pipes write none
    return len((doc or {}).get("junctions") or [])


def summary_row(run: BatchRun, out: Path, status: str, seconds: float | None = None, reason: str | None = None
                ) -> dict:
    """The summary row of one run; a result folder's figures come from its run.json, and `seconds` (this
    batch's wall time on the worker) from the task, else from the run.json of an earlier batch."""
    row = dict.fromkeys(COLUMNS, "")
    row.update(run=run.name, status=status, dataset=str(run.dataset))
    record = read_result(out / run.name) if status in ("mapped", "skipped") else None
    problems = [reason] if reason else []
    if record is not None:
        quality = record.get("quality") or {}
        row.update(method=record.get("method", ""), frames=record.get("frames", ""),
                   keyframes=record.get("keyframes", ""), junctions=_junction_count(out / run.name),
                   quality=quality.get("rating", ""))
        if seconds is None:
            seconds = (record.get("seconds") or {}).get("total")
        damaged = (record.get("footage") or {}).get("damaged") or 0
        problems += list(record.get("problems") or [])
        if damaged:
            problems.append(f"{damaged} damaged frame{'s' if damaged > 1 else ''} skipped")
    if seconds is not None:
        row["seconds"] = f"{seconds:.1f}"
    row["problems"] = "; ".join(problems)
    return row


def write_summary(path: Path, rows: list[dict]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(path, buf.getvalue())


__all__ = ["COLUMNS", "read_result", "summary_row", "write_summary"]
