"""`pipemap observations`: an inspector's list of observations located on the route.

Input CSV: `frame,u,v` (a point) or `frame,u,v,u2,v2` (a pixel box), with optional `id,code,remark,continuous`
(`start`, `finish` or empty) and any other columns, which are kept. Output: the same rows with section, from/to
node, chainage (a box: from its nearest to its farthest located point), clock from/to (a box: the clockwise
arc that covers it), the 3D point of the pixel (a box: its centre), sigmas and the unrolled image it lies in.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from pipemap.errors import PipemapError
from pipemap.inspection.locate import LocatedResult, locate_pixels
from pipemap.output import atomic_write_text, check_new_file

COLUMNS = ["id", "frame", "u", "v", "u2", "v2", "code", "remark", "continuous", "section", "from_node", "to_node",
           "chainage_m", "chainage_to_m", "clock_from_deg", "clock_to_deg", "x", "y", "z", "sigma_chainage_m",
           "sigma_clock_deg", "image", "image_col", "image_row"]
BOX_SAMPLES = 5  # a box is located on a 5 x 5 grid of its pixels


def read_observations(path: Path) -> list[dict]:
    try:
        with Path(path).open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    except FileNotFoundError:
        raise PipemapError("file not found", path) from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise PipemapError(f"cannot read: {exc}", path) from None
    if not rows:
        raise PipemapError("no observations (expected a header frame,u,v and one row per observation)", path)
    missing = [c for c in ("frame", "u", "v") if c not in rows[0]]
    if missing:
        raise PipemapError(f"missing column(s) {', '.join(missing)}", path)
    for i, r in enumerate(rows, start=2):
        try:
            int(r["frame"]), float(r["u"]), float(r["v"])
            if (r.get("u2") or "").strip() or (r.get("v2") or "").strip():
                float(r["u2"]), float(r["v2"])
        except (TypeError, ValueError):
            raise PipemapError("frame must be an integer and u, v (u2, v2) numbers", path, f"line {i}") from None
        if (r.get("continuous") or "").strip() not in ("", "start", "finish"):
            raise PipemapError("continuous must be start, finish or empty", path, f"line {i}")
    return rows


def clock_arc(clock_deg: np.ndarray) -> tuple[float, float]:
    """(from, to) of the shortest clockwise arc that covers the angles: it starts after their widest gap."""
    a = np.sort(np.mod(clock_deg, 360.0))
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    k = int(np.argmax(gaps))
    return float(a[(k + 1) % len(a)]), float(a[k])


def locate_observation(res: LocatedResult, row: dict, settings=None) -> dict:
    frame, u, v = int(row["frame"]), float(row["u"]), float(row["v"])
    box = bool((row.get("u2") or "").strip())
    out = {c: row.get(c, "") for c in COLUMNS}
    out.update({k: val for k, val in row.items() if k not in out})
    if box:
        u2, v2 = float(row["u2"]), float(row["v2"])
        g = np.linspace(0.0, 1.0, BOX_SAMPLES)
        uu, vv = np.meshgrid(u + g * (u2 - u), v + g * (v2 - v))
        px = np.vstack([[(u + u2) / 2, (v + v2) / 2], np.column_stack([uu.ravel(), vv.ravel()])])
    else:
        px = np.array([[u, v]])
    loc = locate_pixels(res, frame, px, settings)
    if not loc.ok[0]:
        raise PipemapError(f"frame {frame} pixel {u:g},{v:g}: the ray meets no mapped wall", key=row.get("id"))
    ok = loc.ok
    c, k = loc.chainage[ok], loc.clock_deg[ok]
    seg = res.route.segments[int(loc.segment[0])]
    nodes = res.route.nodes_around(int(loc.segment[0]))
    out.update(section=seg.name, from_node=nodes[0], to_node=nodes[1],
               chainage_m=f"{(c.min() if box else c[0]):.3f}", chainage_to_m=f"{c.max():.3f}" if box else "",
               sigma_chainage_m=f"{loc.sigma_chainage[0]:.4f}", sigma_clock_deg=f"{loc.sigma_clock_deg[0]:.2f}")
    if box:
        a, b = clock_arc(k)
        out.update(clock_from_deg=f"{a:.1f}", clock_to_deg=f"{b:.1f}")
    else:
        out.update(clock_from_deg=f"{k[0]:.1f}", clock_to_deg="")
    out.update(x=f"{loc.points[0, 0]:.4f}", y=f"{loc.points[0, 1]:.4f}", z=f"{loc.points[0, 2]:.4f}")
    out.update(_image_ref(res, seg.name, float(loc.chainage[0]), float(loc.clock_deg[0])))
    return out


def _image_ref(res: LocatedResult, section: str, chainage: float, clock: float) -> dict:
    """The unrolled image of the section and the (column, row) of the point in it, where there is one."""
    import json

    side = res.folder / "unrolled" / f"{section}.json"
    if not side.exists():
        return {"image": "", "image_col": "", "image_row": ""}
    meta = json.loads(side.read_text())
    c0 = meta.get("chainage_of_column_0_m")
    if c0 is None:  # pipemap-unrolled/1: column 0 is the axis start, placed on the route here
        i = next(i for i, s in enumerate(res.route.segments) if s.name == section)
        c0 = float(res.route.to_route(meta["axis"]["start"], wall=False, segment=[i])[0][0])
    col = (chainage - float(c0)) / meta["metres_per_pixel_along"]
    row = ((np.radians(clock) - meta["phi_of_row_0_rad"]) / meta["phi_per_row_rad"]) % meta["height_px"]
    return {"image": f"unrolled/{meta['image']}", "image_col": f"{col:.1f}", "image_row": f"{row:.1f}"}


def write_observations(path: Path, rows: list[dict], force: bool = False) -> None:
    path = Path(path)
    check_new_file(path, force)
    extra = [k for k in rows[0] if k not in COLUMNS] if rows else []
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS + extra, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    atomic_write_text(path, buf.getvalue())


__all__ = ["COLUMNS", "read_observations", "locate_observation", "write_observations", "clock_arc"]
