"""The route of a result folder: its route.json, or, for network results written before route.json existed,
the route rebuilt from run.json and trajectory.tum (12 o'clock from the image-up estimate)."""

from __future__ import annotations

from pathlib import Path

from pipemap.errors import PipemapError
from pipemap.inspection.network_route import network_route
from pipemap.inspection.route import Route, read_route
from pipemap.trajectory import read_tum


def load_route(folder: str | Path, run: dict) -> Route:
    folder = Path(folder)
    if (folder / "route.json").exists():
        return read_route(folder / "route.json")
    if not run.get("wall_pieces"):
        raise PipemapError("no route.json, and run.json has no wall pieces to build a route from", folder)
    poses = read_tum(folder / "trajectory.tum").matrices()
    route = network_route(run["wall_pieces"], run.get("straight_sections") or [], run.get("junction_passes") or [],
                          poses, float(run.get("pipe_radius_m") or run["wall_pieces"][0]["radius"]))
    if route is None:
        raise PipemapError("no straight piece to build a route from", folder / "run.json")
    return route


__all__ = ["load_route"]
