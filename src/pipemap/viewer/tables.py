"""The two tables the viewer shows: deformation.csv and a located observations CSV (docs/formats.md).

Numbers are parsed once here; an empty cell is None. A table that is present but not what its
header promises is an error naming the file and the line.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from pipemap.errors import PipemapError

DEFORMATION_COLUMNS = ("piece", "chainage_m", "h_m", "source", "points", "diameter_x_m", "diameter_y_m",
                       "diameter_min_m", "diameter_max_m", "ovality_pct", "max_inward_m", "max_outward_m")
DEFORMATION_NEEDED = ("piece", "h_m", "source", "ovality_pct")

OBSERVATION_COLUMNS = ("id", "frame", "u", "v", "u2", "v2", "code", "remark", "continuous", "section", "from_node",
                       "to_node", "chainage_m", "chainage_to_m", "clock_from_deg", "clock_to_deg", "x", "y", "z",
                       "sigma_chainage_m", "sigma_clock_deg", "image")
OBSERVATION_NUMBERS = ("frame", "u", "v", "u2", "v2", "chainage_m", "chainage_to_m", "clock_from_deg",
                       "clock_to_deg", "x", "y", "z", "sigma_chainage_m", "sigma_clock_deg")
OBSERVATION_NEEDED = ("id", "code", "chainage_m", "clock_from_deg")


def _rows(path: Path, needed: tuple[str, ...], what: str) -> tuple[list[str], list[tuple[int, dict]]]:
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = [h.strip() for h in (reader.fieldnames or [])]
            reader.fieldnames = header
            rows = [(reader.line_num, row) for row in reader]
    except FileNotFoundError:
        raise PipemapError("file not found", path) from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise PipemapError(f"cannot read: {exc}", path) from None
    missing = [c for c in needed if c not in header]
    if missing:
        raise PipemapError(f"not {what}: no column {', '.join(missing)}", path)
    return header, rows


def _number(text, path: Path, line: int, column: str) -> float | None:
    text = (text or "").strip()
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        raise PipemapError(f"{column} is not a number: {text!r}", path, f"line {line}") from None
    if not math.isfinite(value):
        raise PipemapError(f"{column} is not finite: {text!r}", path, f"line {line}")
    return value


def read_deformation(path: Path) -> list[dict] | None:
    """deformation.csv's rows with numbers parsed; None when the file is absent."""
    path = Path(path)
    if not path.exists():
        return None
    header, rows = _rows(path, DEFORMATION_NEEDED, "a deformation table")
    out = []
    for line, row in rows:
        rec = {"piece": (row.get("piece") or "").strip(), "source": (row.get("source") or "").strip()}
        for col in DEFORMATION_COLUMNS[1:]:
            if col not in ("source",) and col in header:
                rec[col] = _number(row.get(col), path, line, col)
        if rec.get("h_m") is None or rec.get("ovality_pct") is None:
            raise PipemapError("h_m and ovality_pct must be given", path, f"line {line}")
        out.append(rec)
    return out


def read_observations(path: Path) -> tuple[list[str], list[dict]]:
    """(columns, rows) of a located observations CSV, numbers parsed; other columns kept as text."""
    path = Path(path)
    header, rows = _rows(path, OBSERVATION_NEEDED, "a located observations table (`pipemap observations` "
                                                   "writes one)")
    out = []
    for line, row in rows:
        rec = {k: (v or "").strip() for k, v in row.items() if k}
        for col in OBSERVATION_NUMBERS:
            if col in header:
                rec[col] = _number(row.get(col), path, line, col)
        out.append(rec)
    return header, out


__all__ = ["read_deformation", "read_observations", "DEFORMATION_COLUMNS", "OBSERVATION_COLUMNS"]
