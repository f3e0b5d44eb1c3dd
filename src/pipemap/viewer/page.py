"""viewer.html: one self-contained page of a result folder that opens from file:// with no server and no
network. three.js (vendored, vendor/README.md) comes in as an import map of data: URLs, the data as one JSON
block, the unrolled walls as PNG data URIs."""

from __future__ import annotations

import base64
import html
import json
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from pipemap.config import Settings
from pipemap.errors import PipemapError
from pipemap.output import atomic_write_text, check_new_file
from pipemap.viewer import scene
from pipemap.viewer.tables import read_deformation, read_observations
from pipemap.viewer.walls import place_observation, read_walls

VIEWER = "viewer.html"
OBSERVATIONS = "observations.csv"
DEFORMATION = "deformation.csv"


@dataclass(frozen=True)
class ViewerSummary:
    path: Path
    bytes: int
    seconds: float
    walls: int
    cloud_points: int  # drawn in the 3D view
    observations: int | None  # None: no observations table
    placed: int  # observations with a marker on a wall
    deformation_rows: int | None
    missing: list[str]  # what the result lacks, as the page lists it


def _asset(name: str) -> str:
    return resources.files("pipemap.viewer").joinpath(name).read_text(encoding="utf-8")


def _module_url(name: str) -> str:
    data = resources.files("pipemap.viewer").joinpath("vendor", name).read_bytes()
    return "data:text/javascript;base64," + base64.b64encode(data).decode("ascii")


def viewer_data(result_dir: Path, observations: Path | None, settings: Settings) -> tuple[dict, list]:
    """Everything the page shows, as one JSON-able dict, and the unrolled walls whose images it draws."""
    run = scene.read_run_json(result_dir)
    walls = read_walls(result_dir)
    pieces = scene.read_pieces(run, walls)
    data = {"title": result_dir.resolve().name, "quality": ((run or {}).get("quality") or {}).get("line"),
            "method": (run or {}).get("method", "network" if run and "wall_pieces" in run else None),
            "radius": (run or {}).get("pipe_radius_m"), "trajectory": scene.read_trajectory(result_dir),
            "junctions": scene.read_junctions(result_dir), "pieces": pieces, "up": scene.world_up(pieces),
            "cloud": scene.sample_cloud(result_dir, settings.viewer.cloud_points, settings.seed),
            "walls": [w.page_data(i) for i, w in enumerate(walls)],
            "deformation": read_deformation(result_dir / DEFORMATION), "observations": None}
    if observations is not None:
        columns, rows = read_observations(observations)
        for row in rows:
            row["marker"] = place_observation(row, walls)
        data["observations"] = {"file": observations.name, "columns": columns, "rows": rows}
    data["missing"] = _missing(data, run)
    return data, walls


def _missing(data: dict, run: dict | None) -> list[str]:
    notes = []
    if run is None:
        notes.append("run.json: no run record")
    if data["trajectory"] is None:
        notes.append("trajectory.tum: no trajectory")
    if data["junctions"] is None:
        notes.append("junctions.yaml: no junctions")
    if data["cloud"] is None:
        notes.append("appearance.ply: no appearance map (or viewer.cloud_points is 0)")
    if not data["walls"]:
        notes.append("unrolled/: no unrolled walls")
    elif any(w["alongKind"] == "h" for w in data["walls"]):
        notes.append("unrolled/: no chainage in the sidecars (a result before pipemap-unrolled/2): distances "
                     "along each wall are h from its piece's start")
    if data["deformation"] is None:
        notes.append("deformation.csv: no deformation table")
    if data["observations"] is None:
        notes.append("observations: no located observations CSV (`pipemap observations RESULT OBS.csv`)")
    return notes


def render_page(data: dict, walls: list) -> str:
    """The HTML text: template, style, script, the import map of the vendored modules, the data and the walls'
    images (img elements, so that the page's load event waits for them)."""
    imports = {"three": _module_url("three.module.min.js"),
               "three/addons/controls/OrbitControls.js": _module_url("OrbitControls.js")}
    blob = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")
    images = "\n".join(f'<img id="{w["image"]}" alt="" src="{wall.data_uri()}">'
                       for w, wall in zip(data["walls"], walls))
    page = _asset("viewer.html")
    for key, value in (("{{TITLE}}", html.escape(f"pipemap viewer: {data['title']}")),
                       ("{{STYLE}}", _asset("viewer.css")), ("{{IMPORTMAP}}", json.dumps({"imports": imports})),
                       ("{{SCRIPT}}", _asset("viewer.js")), ("{{DATA}}", blob), ("{{IMAGES}}", images)):
        page = page.replace(key, value, 1)
    return page


def _refuse_inputs(out: Path, result_dir: Path, observations) -> None:
    """--out never names a file the page is made from."""
    inputs = [result_dir / n for n in ("run.json", "trajectory.tum", "junctions.yaml", "appearance.ply", DEFORMATION,
                                       OBSERVATIONS)]
    inputs += list((result_dir / "unrolled").glob("*")) if (result_dir / "unrolled").is_dir() else []
    if observations is not None:
        inputs.append(Path(observations))
    target = out.resolve()
    if any(p.exists() and p.resolve() == target for p in inputs):
        raise PipemapError("is one of the files the viewer is made from; choose another --out", out)


def write_viewer(result_dir: str | Path, out: str | Path | None = None, observations: str | Path | None = None,
                 settings: Settings | None = None, force: bool = False) -> ViewerSummary:
    """Write the viewer page of `result_dir` (default RESULT/viewer.html). `observations`: a located
    observations CSV; by default RESULT/observations.csv when there is one. An existing page is replaced only
    with `force`, and only once the new one is complete."""
    t0 = time.perf_counter()
    result_dir = Path(result_dir)
    if not result_dir.is_dir():
        raise PipemapError("result folder not found" if not result_dir.exists() else "not a folder", result_dir)
    if not any((result_dir / name).exists() for name in ("run.json", "trajectory.tum", "unrolled")):
        raise PipemapError("not a result folder: no run.json, trajectory.tum or unrolled/ (pipemap run writes them)",
                           result_dir)
    out = Path(out) if out is not None else result_dir / VIEWER
    if out.exists() and out.is_dir():
        raise PipemapError("is a folder; give a file name for --out", out)
    if observations is None and (result_dir / OBSERVATIONS).is_file():
        observations = result_dir / OBSERVATIONS
    _refuse_inputs(out, result_dir, observations)
    check_new_file(out, force)
    data, walls = viewer_data(result_dir, None if observations is None else Path(observations),
                              settings or Settings())
    text = render_page(data, walls)
    atomic_write_text(out, text)
    obs = data["observations"]
    return ViewerSummary(out, len(text.encode()), time.perf_counter() - t0, len(data["walls"]),
                         (data["cloud"] or {}).get("count", 0), None if obs is None else len(obs["rows"]),
                         0 if obs is None else sum(r["marker"] is not None for r in obs["rows"]),
                         None if data["deformation"] is None else len(data["deformation"]), data["missing"])


__all__ = ["ViewerSummary", "write_viewer", "viewer_data", "render_page", "VIEWER"]
