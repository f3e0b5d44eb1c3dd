"""The runs of a batch: a manifest (YAML or CSV) of dataset folders with optional per-run settings, or a glob.

Paths in a manifest are relative to the manifest's folder. A run's settings are its `config` file (or else the
batch's --config), then the batch's --set overrides, then its own `set`; a run whose method or settings are
wrong fails alone."""

from __future__ import annotations

import csv
import glob as globmod
import os
from dataclasses import dataclass, field
from pathlib import Path

from pipemap.config import Settings, load_settings
from pipemap.errors import PipemapError
from pipemap.methods import check_method
from pipemap.yamlfile import read_yaml

FORMAT = "pipemap-batch/1"
KEYS = ("dataset", "name", "method", "config", "set")
SUMMARY_FILE = "batch.csv"


@dataclass
class BatchRun:
    name: str  # the result folder's name under the batch's --out
    dataset: Path  # absolute
    method: str = "auto"
    settings: Settings | None = None  # None: the settings could not be made (see `problem`)
    problem: str | None = None  # why the run cannot start, one line
    overrides: list[str] = field(default_factory=list)


def read_runs(spec: str, method: str = "auto", config: Path | None = None, overrides: tuple[str, ...] = ()
              ) -> list[BatchRun]:
    """The runs `spec` names: a .yaml/.yml or .csv manifest, or else a glob of dataset folders (or of their
    dataset.yaml files). The batch-wide `method`, `config` and `overrides` apply to every run first."""
    path = Path(os.path.expanduser(spec))
    manifest = path.suffix.lower() in (".yaml", ".yml", ".csv") and path.name != "dataset.yaml"
    if manifest and path.is_file():
        rows = _yaml_rows(path) if path.suffix.lower() != ".csv" else _csv_rows(path)
        base = path.resolve().parent
    elif manifest:
        raise PipemapError("manifest not found", path)
    elif path.is_dir() or (path.name == "dataset.yaml" and path.is_file()):
        if path.is_dir() and not (path / "dataset.yaml").is_file():
            raise PipemapError("is a folder without dataset.yaml; give a manifest (.yaml, .csv) or a glob", path)
        rows, base = [(str(path), {"dataset": str(path)})], Path.cwd()
    else:
        rows, base = _glob_rows(spec), Path.cwd()
    runs = [_run(where, row, base, method, config, overrides) for where, row in rows]
    _check_names(runs, rows)
    return runs


def _yaml_rows(path: Path) -> list[tuple[str, dict]]:
    data = read_yaml(path, "manifest")
    fmt = data.get("format", FORMAT)
    if fmt != FORMAT:
        raise PipemapError(f"expected '{FORMAT}', found {fmt!r}", path, "format")
    runs = data.get("runs")
    if not isinstance(runs, list) or not runs:
        raise PipemapError("expected a non-empty list of runs", path, "runs")
    rows = []
    for k, item in enumerate(runs):
        where = f"{path}: runs[{k}]"
        if isinstance(item, str):
            item = {"dataset": item}
        if not isinstance(item, dict):
            raise PipemapError("expected a dataset path or a mapping with dataset:", where)
        unknown = sorted(set(item) - set(KEYS))
        if unknown:
            raise PipemapError(f"unknown key {unknown[0]!r} (expected {', '.join(KEYS)})", where)
        sets = item.get("set") or []
        if isinstance(sets, str):
            sets = [sets]
        if not isinstance(sets, list):
            raise PipemapError("expected a list of section.key=value", where, "set")
        rows.append((where, dict(item, set=[str(s) for s in sets])))
    return rows


def _csv_rows(path: Path) -> list[tuple[str, dict]]:
    try:
        with open(path, newline="") as fh:
            table = list(csv.DictReader(fh, skipinitialspace=True))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise PipemapError(f"cannot read CSV: {exc}", path) from None
    if not table or "dataset" not in table[0]:
        raise PipemapError("expected a header line with a dataset column and at least one run", path)
    unknown = sorted(k for k in table[0] if k not in KEYS)
    if unknown:
        raise PipemapError(f"unknown column {unknown[0]!r} (expected {', '.join(KEYS)})", path)
    rows = []
    for k, row in enumerate(table):
        item = {key: (value or "").strip() for key, value in row.items() if value and value.strip()}
        item["set"] = [s.strip() for s in item.get("set", "").split(";") if s.strip()]
        rows.append((f"{path}: line {k + 2}", item))
    return rows


def _glob_rows(pattern: str) -> list[tuple[str, dict]]:
    found = sorted(Path(p) for p in globmod.glob(os.path.expanduser(pattern)))
    folders = [p if p.is_dir() else p.parent for p in found
               if (p.is_dir() and (p / "dataset.yaml").is_file()) or p.name == "dataset.yaml"]
    if not folders:
        raise PipemapError("no manifest file and no dataset folder (with dataset.yaml) matches", pattern)
    return [(str(p), {"dataset": str(p), "set": []}) for p in folders]


def _run(where: str, row: dict, base: Path, method: str, config: Path | None, overrides) -> BatchRun:
    if not row.get("dataset"):
        raise PipemapError("no dataset given", where, "dataset")
    dataset = (base / os.path.expanduser(str(row["dataset"]))).resolve()
    dataset = dataset.parent if dataset.name == "dataset.yaml" else dataset
    name = str(row.get("name") or dataset.name)
    run = BatchRun(name, dataset, str(row.get("method") or method))
    try:
        check_method(run.method, where, "method")
        run_config = (base / str(row["config"])).resolve() if row.get("config") else config
        run.overrides = list(overrides) + list(row.get("set") or [])
        if any(s.split("=", 1)[0].strip().startswith("batch.") for s in row.get("set") or []):
            raise PipemapError("batch settings apply to the whole batch (its --set), not to one run", where, "set")
        run.settings = load_settings(run_config, run.overrides)
    except PipemapError as exc:
        run.problem = exc.line() if exc.where not in (None, "--set") else f"{where}: {exc.line()}"
    return run


def _check_names(runs: list[BatchRun], rows) -> None:
    seen: dict[str, str] = {}
    for run, (where, _) in zip(runs, rows):
        bad = not run.name or run.name.startswith(".") or "/" in run.name or run.name == SUMMARY_FILE
        if bad or os.sep in run.name:
            raise PipemapError(f"{run.name!r} cannot name a result folder", where, "name")
        if run.name in seen:
            raise PipemapError(f"two runs are named {run.name!r} ({seen[run.name]} too); give one a name:", where,
                               "name")
        seen[run.name] = where


__all__ = ["FORMAT", "SUMMARY_FILE", "BatchRun", "read_runs"]
