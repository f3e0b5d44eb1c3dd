"""Helpers shared by the mapping tests: the simulator's texture on a map's grid, correlations."""

from __future__ import annotations

import cv2
import numpy as np


def albedo_on_grid(case, pm) -> np.ndarray:
    """The simulator's baked wall albedo at a piece's grid points (H, W). The simulator's s runs
    the other way round (anticlockwise looking along the axis) from phi, from the same 12 o'clock."""
    i = [p.name for p in case.pieces].index(pm.piece.name)
    pipe = case.scene.pipes[i]
    assert pipe.id == pm.piece.name
    surf = case.texture.surface(pipe.id, pipe.extend_start + pipe.length + pipe.extend_end,
                                2 * np.pi * case.scene.radius)
    hh, ph = np.meshgrid(pm.grid.h, pm.grid.phi, indexing="ij")
    return surf.sample(hh + pipe.extend_start, -ph * case.scene.radius, 0.004)


def high_pass(values: np.ndarray, seen: np.ndarray, sigma: float = 6.0) -> np.ndarray:
    """values minus their local mean over the seen points: removes the LED lighting's slow changes."""
    x = np.where(seen, values, 0).astype(np.float32)
    w = seen.astype(np.float32)
    mean = cv2.GaussianBlur(x, (0, 0), sigma) / np.maximum(cv2.GaussianBlur(w, (0, 0), sigma), 1e-6)
    return x - mean


def texture_correlation(case, amap) -> float:
    """Correlation of the map with the baked albedo, both high-passed, over every seen point."""
    a, b = [], []
    for pm in amap.pieces:
        seen = pm.seen
        if not seen.any():
            continue
        a.append(high_pass(pm.intensity, seen)[seen])
        b.append(high_pass(albedo_on_grid(case, pm), seen)[seen])
    return float(np.corrcoef(np.concatenate(a), np.concatenate(b))[0, 1])
