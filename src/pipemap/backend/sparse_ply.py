"""sparse.ply: the sparse scene points as a binary PLY with float32 x y z (spec/formats.md)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from pipemap.errors import PipemapError
from pipemap.output import atomic_write_bytes


def write_sparse_ply(path: str | Path, points: np.ndarray) -> None:
    """Write (M, 3) points (non-finite rows dropped) atomically."""
    P = np.asarray(points, float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    vertex = np.empty(len(P), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    vertex["x"], vertex["y"], vertex["z"] = P[:, 0], P[:, 1], P[:, 2]
    buf = io.BytesIO()
    PlyData([PlyElement.describe(vertex, "vertex")], text=False, byte_order="<",
            comments=["pipemap sparse scene points, metres, world frame of trajectory.tum"]).write(buf)
    atomic_write_bytes(Path(path), buf.getvalue())


def read_sparse_ply(path: str | Path) -> np.ndarray:
    """(M, 3) float64 points of a sparse.ply."""
    path = Path(path)
    try:
        ply = PlyData.read(str(path))
        v = ply["vertex"]
        return np.stack([np.asarray(v["x"], float), np.asarray(v["y"], float), np.asarray(v["z"], float)], axis=-1)
    except FileNotFoundError:
        raise PipemapError("file not found", path) from None
    except (KeyError, ValueError, OSError) as exc:
        raise PipemapError(f"not a sparse point PLY ({exc})", path) from None


__all__ = ["write_sparse_ply", "read_sparse_ply"]
