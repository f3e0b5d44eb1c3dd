"""`pipemap export`: sections as CSV and the network as GeoJSON, for an inspector's software.

The GeoJSON is in a local metric frame: origin at the route's start, z = 12 o'clock (up), x = the first
segment's direction across up, y = z x x; coordinates are (x, y, z) in metres. Given the start and end
manholes' plan coordinates (e.g. easting, northing), the plan is mapped onto them by the 2D similarity that
takes the route's start and end there (the scale it needed is reported: ~1 for a good survey).

RFC 7946 takes GeoJSON coordinates as WGS84 longitude/latitude, which neither frame is: its section 4 leaves other
systems to a prior arrangement, so the file says what it holds (`properties.frame`, `properties.crs`) and, for
manhole coordinates in a named projected system (`crs`, e.g. EPSG:27700), carries the GeoJSON 2008 `crs` member
that GDAL and QGIS read. Turning projected coordinates into longitude/latitude is left to those tools
(`ogr2ogr -t_srs EPSG:4326`): a datum transformation is theirs to get right.
"""

from __future__ import annotations

import csv
import io
import json

import numpy as np

from pipemap.errors import PipemapError
from pipemap.inspection.route import Route

SECTION_COLUMNS = ["section", "kind", "from_node", "to_node", "chainage_m", "chainage_to_m", "length_m",
                   "diameter_mm"]


def sections_csv(route: Route) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(SECTION_COLUMNS)
    for i, seg in enumerate(route.segments):
        w.writerow([seg.name, seg.kind, *route.nodes_around(i),
                    f"{seg.chainage_start:.3f}", f"{seg.chainage_end:.3f}", f"{seg.length:.3f}",
                    f"{2000 * route.radius:.0f}"])
    return buf.getvalue()


def local_frame(route: Route) -> tuple[np.ndarray, np.ndarray]:
    """(origin, R) with rows of R the local x, y, z axes in the result's world frame."""
    first = route.segments[0]
    z = first.up / np.linalg.norm(first.up)
    d = first.end - first.start
    x = d - (d @ z) * z
    x /= np.linalg.norm(x)
    return first.start.copy(), np.stack([x, np.cross(z, x), z])


def plan_similarity(local_start, local_end, start_en, end_en) -> tuple[np.ndarray, np.ndarray, float]:
    """(A (2, 2), b (2,), scale): plan point p maps to A p + b, taking the route's start and end (local plan
    coordinates) onto the manholes'."""
    a, b = np.asarray(local_start, float)[:2], np.asarray(local_end, float)[:2]
    p, q = np.asarray(start_en, float)[:2], np.asarray(end_en, float)[:2]
    da, dp = b - a, q - p
    if np.linalg.norm(da) < 1.0:
        raise PipemapError("the route ends within 1 m of its start (in plan): the two manholes cannot fix its "
                           "direction", key="--end-manhole")
    za, zp = complex(*da), complex(*dp)
    m = zp / za
    A = np.array([[m.real, -m.imag], [m.imag, m.real]])
    return A, p - A @ a, abs(m)


def network_geojson(route: Route, start_en=None, end_en=None, crs: str | None = None, step_m: float = 0.05) -> dict:
    """The route's segments (LineStrings) and nodes (Points) in the local frame, or on the manholes' plan
    coordinates (both or neither) in the projected system `crs` names (e.g. EPSG:27700; None: unnamed)."""
    if crs is not None and start_en is None:
        raise PipemapError("a coordinate system only applies to manhole coordinates: give --start-manhole and "
                           "--end-manhole too", key="--crs")
    origin, R = local_frame(route)

    def local(points):
        return (np.atleast_2d(points) - origin) @ R.T

    A, b, scale = np.eye(2), np.zeros(2), 1.0
    if start_en is not None and end_en is not None:
        ends = local(np.array([route.from_route(0.0, 0.0, 0.0)[0], route.from_route(route.length, 0.0, 0.0)[0]]))
        A, b, scale = plan_similarity(ends[0], ends[1], start_en, end_en)

    def place(points):
        p = local(points)
        out = np.column_stack([p[:, :2] @ A.T + b, p[:, 2]])
        return [[round(float(v), 4) for v in row] for row in out]

    feats = []
    for seg in route.segments:
        n = max(2, int(np.ceil(seg.length / step_m)) + 1) if seg.kind == "arc" else 2
        c = np.linspace(seg.chainage_start, seg.chainage_end, n)
        axis = route.from_route(c, 0.0, 0.0, segment=np.full(n, route.segments.index(seg)))
        feats.append({"type": "Feature", "geometry": {"type": "LineString", "coordinates": place(axis)},
                      "properties": {"kind": "section", "section": seg.name, "shape": seg.kind,
                                     "chainage_m": round(seg.chainage_start, 3),
                                     "chainage_to_m": round(seg.chainage_end, 3),
                                     "diameter_mm": round(2000 * route.radius)}})
    nodes = [("start", "manhole", 0.0)] + list(route.nodes) + [("end", "manhole", route.length)]
    for jid, jtype, c in nodes:
        feats.append({"type": "Feature",
                      "geometry": {"type": "Point", "coordinates": place(route.from_route(c, 0.0, 0.0))[0]},
                      "properties": {"kind": "node", "id": jid, "type": jtype, "chainage_m": round(c, 3)}})
    frame = "local metric: origin at the route start, x along the first section, z up (12 o'clock)"
    crs_note = "local engineering frame in metres (not WGS84 longitude/latitude)"
    if start_en is not None:
        frame = "plan coordinates of the manholes given (a similarity in the plane), z metres above the start"
        crs_note = crs or "the manholes' plan coordinate system (unnamed; not WGS84 longitude/latitude)"
    doc = {"type": "FeatureCollection", "features": feats,
           "properties": {"frame": frame, "crs": crs_note, "scale": round(scale, 6),
                          "route_length_m": round(route.length, 3)}}
    if crs is not None:
        doc["crs"] = {"type": "name", "properties": {"name": _crs_urn(crs)}}
    return doc


def _crs_urn(crs: str) -> str:
    """EPSG:27700 -> urn:ogc:def:crs:EPSG::27700 (the form GDAL reads); anything else as given."""
    auth, _, code = crs.strip().partition(":")
    if auth.upper() == "EPSG" and code.isdigit():
        return f"urn:ogc:def:crs:EPSG::{code}"
    if crs.startswith("urn:ogc:def:crs:"):
        return crs
    raise PipemapError(f"expected a coordinate system as EPSG:<code>, got {crs!r}", key="--crs")


def dumps_geojson(doc: dict) -> str:
    return json.dumps(doc, indent=1) + "\n"


__all__ = ["sections_csv", "network_geojson", "plan_similarity", "local_frame", "dumps_geojson"]
