"""`pipemap run`'s deformation stage: the slices of every straight piece from the sparse points (triangulated
again without the cylinder term) and from the dense wall search, written as deformation.csv and
deformation.png; returns run.json's `deformation` record."""

from __future__ import annotations

import io
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pipemap.backend.free_points import free_points
from pipemap.config import Settings
from pipemap.inspection.route import piece_start_chainage
from pipemap.mapping.deformation import SliceProfile, deformation_csv, sparse_profiles, summary
from pipemap.mapping.wall import WallPiece
from pipemap.output import atomic_write_bytes, atomic_write_text


@dataclass(frozen=True)
class SparseDeformation:
    rows: list[SliceProfile]  # the straight pieces' slices from the sparse points
    free_points: int  # points triangulated again without the cylinder term, and valid
    points: int  # of so many tracks
    seconds: float


def sparse_deformation(pipe_map, pieces: list[WallPiece], radius: float, settings: Settings) -> SparseDeformation:
    """The slices of the unrolled (straight) pieces from the sparse points, triangulated again without the
    cylinder term (it reads pipe_map only, so it may run beside the appearance map)."""
    s = settings.deformation
    t0 = time.perf_counter()
    points, valid = free_points(pipe_map.keyframes, pipe_map.poses, pipe_map.point_tracks,
                                min_parallax_deg=s.min_parallax_deg, max_ray_error_deg=s.max_ray_error_deg)
    pts = points[valid]
    rows: list[SliceProfile] = []
    for piece in (p for p in pieces if p.unroll):
        rows += sparse_profiles(piece, pts, radius, s)
    return SparseDeformation(rows, int(valid.sum()), int(len(valid)), time.perf_counter() - t0)


def measure_deformation(pipe_map, pieces: list[WallPiece], radius: float, settings: Settings,
                        dense=None, route=None, sparse: SparseDeformation | None = None
                        ) -> tuple[list[SliceProfile], dict]:
    """The slices of the unrolled (straight) pieces, sparse then dense, and figures for run.json.
    `dense(piece) -> list[SliceProfile]` measures one piece densely (None: sparse only); with `route`
    (inspection.Route) every slice gets its chainage; `sparse`: sparse_deformation's result, when it ran
    already."""
    s = settings.deformation
    sparse = sparse or sparse_deformation(pipe_map, pieces, radius, settings)
    rows = list(sparse.rows)
    straight = [p for p in pieces if p.unroll]
    t1 = time.perf_counter()
    if dense is not None and s.dense:
        for piece in straight:
            rows += dense(piece)
    if route is not None:
        start = {p.name: piece_start_chainage(route, p) for p in straight}
        rows = [replace(r, chainage_m=round(start[r.piece] + r.h_m, 4)) for r in rows]
    record = summary(rows)
    record.update(free_points=sparse.free_points, points=sparse.points,
                  seconds={"sparse": round(sparse.seconds, 3), "dense": round(time.perf_counter() - t1, 3)})
    return rows, record


def write_deformation(folder: Path, rows: list[SliceProfile], radius: float) -> None:
    folder = Path(folder)
    atomic_write_text(folder / "deformation.csv", deformation_csv(rows))
    atomic_write_bytes(folder / "deformation.png", deformation_plot(rows, radius))


def deformation_plot(rows: list[SliceProfile], radius: float) -> bytes:
    """Ovality and the largest inward deviation along each piece, sparse and dense (PNG bytes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pieces = list(dict.fromkeys(p.piece for p in rows))
    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    offset, ticks = 0.0, []
    for name in pieces:
        mine = [p for p in rows if p.piece == name]
        length = max(p.h_m for p in mine)
        for source, style in (("sparse", "o-"), ("dense", "s--")):
            sel = [p for p in mine if p.source == source]
            if not sel:
                continue
            x = offset + np.array([p.h_m for p in sel])
            axes[0].plot(x, [p.ovality_pct for p in sel], style, ms=3, label=f"{name} {source}")
            axes[1].plot(x, [1000 * p.max_inward_m for p in sel], style, ms=3, label=f"{name} {source}")
        ticks.append((offset, name))
        offset += length + 0.2
    axes[0].set_ylabel("ovality (%)")
    axes[1].set_ylabel("largest inward\ndeviation (mm)")
    axes[1].set_xlabel("h along each straight piece (m), pieces side by side")
    axes[0].set_title(f"deformation every slice, a-priori radius {radius * 1000:.1f} mm")
    for ax in axes:
        ax.grid(alpha=0.3)
        for x, _ in ticks:
            ax.axvline(x, color="0.8", lw=0.8)
    if rows:
        axes[0].legend(fontsize=7, ncol=4)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()
